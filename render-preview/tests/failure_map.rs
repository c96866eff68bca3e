//! The failure-region generator (`render_preview::failure_map`) on a tiny case: the thin
//! two-sided leaf of tests/method_failures.rs, face-on and 88° off its normal. That test
//! measured canopy's IoU at 0.971 face-on and 0.480 at 88° (its whole-sphere discs make the
//! edge-on line a band) and zbuffer's at 0.996 and 0.997, so the map must report canopy as
//! holding face-on and breaking edge-on, and zbuffer as holding at both.

use render_preview::failure_map::{self, Mode};
use render_preview::{failure_chart, Method};

#[test]
fn the_map_reports_canopy_breaking_edge_on_and_zbuffer_holding() {
    let dir = tempfile::tempdir().unwrap();
    let sweeps = failure_map::run(&[Mode::ThinLeaf], &[Method::Zbuffer, Method::Canopy], Some(&[0.0, 88.0]), 160, dir.path()).unwrap();
    assert_eq!(sweeps.len(), 2);
    for s in &sweeps {
        eprintln!("{} {:?}", s.method, s.samples);
        assert_eq!(s.samples.iter().map(|p| p.param).collect::<Vec<_>>(), [0.0, 88.0]);
        let (holds, breaks) = failure_map::regions(s);
        match s.method {
            Method::Canopy => assert_eq!((holds.as_str(), breaks.as_str()), ("0", "88"), "{s:?}"),
            _ => assert_eq!((holds.as_str(), breaks.as_str()), ("0, 88", "–"), "{s:?}"),
        }
    }
    let md = failure_map::markdown(&sweeps);
    assert!(md.contains("| canopy | 0 | 88 |"), "{md}");
    // The chart is written in both formats.
    let (png, svg) = (dir.path().join("f.png"), dir.path().join("f.svg"));
    failure_chart::write(&sweeps, &png, &svg).unwrap();
    assert!(std::fs::metadata(&png).unwrap().len() > 1000 && std::fs::read_to_string(&svg).unwrap().contains("thin two-sided leaf"));
}
