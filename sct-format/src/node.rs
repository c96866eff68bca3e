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
