//! The decoded scene node (thesis §3.4.1, §5.1): what every profile decodes to.

/// A scene node's attributes as a reader sees them after decoding.
///
/// Leaves are surface samples; an internal node bounds its two children and carries their
/// merged attributes (see [`crate::geometry`]).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Node {
    /// Sphere centre.
    pub center: [f32; 3],
    /// Sphere radius (> 0 for a valid node).
    pub radius: f32,
    /// Unit axis of the normal cone.
    pub normal: [f32; 3],
    /// Normal-cone semi-angle in radians, in [0, π]; obtuse cones are allowed and π means
    /// "any direction".
    pub cone: f32,
    /// Surface area represented by the node (sum over its leaves).
    pub area: f32,
    /// Area-weighted RGBA colour, straight (not premultiplied) alpha.
    pub color: [u8; 4],
}

impl Node {
    /// True when every float attribute is finite, the radius and area are non-negative and
    /// the cone lies in [0, π].
    pub fn is_finite(&self) -> bool {
        self.center.iter().chain(self.normal.iter()).all(|v| v.is_finite())
            && self.radius.is_finite()
            && self.radius >= 0.0
            && self.area.is_finite()
            && self.area >= 0.0
            && self.cone.is_finite()
            && (0.0..=std::f32::consts::PI).contains(&self.cone)
    }
}

/// For messages: `centre (x, y, z), radius r, normal (x, y, z) ± c rad, area a, colour
/// #rrggbbaa`, never a Rust debug structure.
impl std::fmt::Display for Node {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [x, y, z] = self.center;
        let [nx, ny, nz] = self.normal;
        let [r, g, b, a] = self.color;
        write!(
            f,
            "centre ({x}, {y}, {z}), radius {}, normal ({nx}, {ny}, {nz}) ± {} rad, area {}, colour #{r:02x}{g:02x}{b:02x}{a:02x}",
            self.radius, self.cone, self.area
        )
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn nodes_print_as_text() {
        let n = super::Node { center: [1e30, 0.0, 2.5], radius: f32::INFINITY, color: [255, 0, 16, 255], ..Default::default() };
        let s = n.to_string();
        assert_eq!(s, "centre (1000000000000000000000000000000, 0, 2.5), radius inf, normal (0, 0, 0) ± 0 rad, area 0, colour #ff0010ff");
        let t = crate::Similarity { translation: [1.0, f64::NAN, 0.0], rotation: [0.0, 0.0, 0.0, 1.0], scale: 2.0 };
        assert_eq!(t.to_string(), "translation (1, NaN, 0), rotation (0, 0, 0, 1), scale 2");
    }
}
