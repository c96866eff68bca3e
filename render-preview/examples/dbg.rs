fn main() {
    let mesh = render_preview::synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 24, [0.8, 0.3, 0.2, 1.0]);
    let leaves = render_preview::synth::sample_mesh(&mesh, 0.02);
    let maxr = leaves.iter().map(|l| l.radius).fold(0.0f32, f32::max);
    println!("{} leaves, max leaf r {maxr}", leaves.len());
    let t = render_preview::synth::build_tree(leaves).unwrap();
    for d in 0..t.level_count().min(8) {
        let r = t.level(d);
        let mr = t.nodes()[r.clone()].iter().map(|n| n.radius).fold(0.0f32, f32::max);
        println!("level {d}: {} nodes, max r {mr}", r.len());
    }
}
