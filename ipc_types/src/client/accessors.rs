//! The typed accessors of one node or edge record, shared by the owned graph's views
//! ([`NodeView`](crate::NodeView), [`EdgeView`](crate::EdgeView)) and the borrowed sample's
//! ([`NodeRef`](crate::NodeRef), [`EdgeRef`](crate::EdgeRef)), so both read a record alike.
//!
//! Each macro expands into an `impl<'a>` block whose type has `fn wire(&self) -> &'a Node` (or
//! `Edge`); the lifetime is passed in, as macro hygiene requires. Kinds and origins were checked
//! when the graph was taken ([`check_message`](crate::check_message)), so decoding them cannot
//! fail.

/// The accessors of a node record; `$a` is the lifetime of `wire()`'s reference.
macro_rules! node_record_accessors {
    ($a:lifetime) => {
        /// Stable node id.
        pub fn id(&self) -> u32 {
            self.wire().id
        }

        /// Object or part.
        pub fn kind(&self) -> $crate::NodeKind {
            // Checked when the graph was taken (check_message).
            $crate::NodeKind::from_u8(self.wire().kind).unwrap_or_default()
        }

        /// `true` for an object node.
        pub fn is_object(&self) -> bool {
            self.kind() == $crate::NodeKind::Object
        }

        /// `true` for a part node.
        pub fn is_part(&self) -> bool {
            self.kind() == $crate::NodeKind::Part
        }

        /// The voted label.
        pub fn label(&self) -> &$a str {
            self.wire().label_str()
        }

        /// Confidence in [0, 1].
        pub fn confidence(&self) -> f32 {
            self.wire().confidence
        }

        /// Centre of the node's points, world frame, metres.
        pub fn centre_m(&self) -> [f32; 3] {
            self.wire().centre_m
        }

        /// Minimum corner of the axis-aligned box, world frame, metres.
        pub fn box_min_m(&self) -> [f32; 3] {
            self.wire().box_min_m
        }

        /// Maximum corner of the axis-aligned box, world frame, metres.
        pub fn box_max_m(&self) -> [f32; 3] {
            self.wire().box_max_m
        }

        /// Extent of the axis-aligned box along each world axis, metres.
        pub fn size_m(&self) -> [f32; 3] {
            let (min, max) = (self.box_min_m(), self.box_max_m());
            [max[0] - min[0], max[1] - min[1], max[2] - min[2]]
        }

        /// The gravity-aligned oriented box: its centre (world frame, metres), its size along its
        /// first, second and up axes (metres) and its yaw about the world's up axis (radians in
        /// `(-pi/2, pi/2]`); [`Node`](crate::Node)'s docs define the axes.
        pub fn oriented_box(&self) -> ([f32; 3], [f32; 3], f32) {
            let n = self.wire();
            (n.obb_centre_m, n.obb_size_m, n.obb_yaw_rad)
        }

        /// The oriented box's four bottom corners, counter-clockwise seen from above, for a world
        /// with +z up (a robot's map frame): the node's footprint on the floor, world frame, metres.
        pub fn footprint_z_up_m(&self) -> [[f32; 2]; 4] {
            let ([cx, cy, _], [sx, sy, _], yaw) = self.oriented_box();
            let (sin, cos) = yaw.sin_cos();
            let corner = |a: f32, b: f32| {
                let (u, v) = (a * sx * 0.5, b * sy * 0.5);
                [cx + cos * u - sin * v, cy + sin * u + cos * v]
            };
            [corner(-1.0, -1.0), corner(1.0, -1.0), corner(1.0, 1.0), corner(-1.0, 1.0)]
        }

        /// Keyframe detections fused into this node.
        pub fn observation_count(&self) -> u32 {
            self.wire().observation_count
        }

        /// Stamp of the last keyframe that observed this node, nanoseconds.
        pub fn last_seen_stamp_ns(&self) -> u64 {
            self.wire().last_seen_stamp_ns
        }

        /// Bit set over [`AFFORDANCES`](crate::AFFORDANCES).
        pub fn affordance_bits(&self) -> u16 {
            self.wire().affordance_bits
        }

        /// Names of the node's affordances, in canonical order.
        pub fn affordances(&self) -> impl Iterator<Item = &'static str> + use<> {
            $crate::affordance_names(self.affordance_bits())
        }

        /// Each of the node's affordances with its origin (knowledge, llm, knowledge+llm; geometry
        /// for one the publisher gave no origin), in canonical order.
        pub fn affordance_origins(&self) -> impl Iterator<Item = (&'static str, $crate::EdgeOrigin)> + use<> {
            let n = self.wire();
            $crate::affordance_origins(n.affordance_bits, n.affordance_knowledge_bits, n.affordance_llm_bits)
        }

        /// Where the node's affordance `name` came from; `None` when the node does not afford it
        /// (or `name` is outside [`AFFORDANCES`](crate::AFFORDANCES)).
        pub fn affordance_origin(&self, name: &str) -> Option<$crate::EdgeOrigin> {
            self.wire().affordance_origin($crate::AFFORDANCES.iter().position(|a| *a == name)?)
        }

        /// `true` when the node affords `name` (`false` for names outside
        /// [`AFFORDANCES`](crate::AFFORDANCES)).
        pub fn has_affordance(&self, name: &str) -> bool {
            $crate::affordance_bits([name]).is_ok_and(|bits| self.affordance_bits() & bits == bits)
        }

        /// Id of the parent object of a part (`None` for objects and unattached parts).
        pub fn parent_id(&self) -> Option<u32> {
            let id = self.wire().parent_id;
            (id != $crate::NO_NODE).then_some(id)
        }
    };
}

/// The accessors of an edge record; `$a` is the lifetime of `wire()`'s reference.
macro_rules! edge_record_accessors {
    ($a:lifetime) => {
        /// Source node id.
        pub fn source_id(&self) -> u32 {
            self.wire().source_id
        }

        /// Target node id.
        pub fn target_id(&self) -> u32 {
            self.wire().target_id
        }

        /// Spatial or functional.
        pub fn kind(&self) -> $crate::EdgeKind {
            // Checked when the graph was taken (check_message).
            $crate::EdgeKind::from_u8(self.wire().kind).unwrap_or_default()
        }

        /// Where the edge came from.
        pub fn origin(&self) -> $crate::EdgeOrigin {
            // Checked when the graph was taken (check_message).
            $crate::EdgeOrigin::from_u8(self.wire().origin).unwrap_or_default()
        }

        /// Canonical relation id (see [`relation_phrase`](crate::relation_phrase)).
        pub fn relation_id(&self) -> u16 {
            self.wire().relation_id
        }

        /// The relation phrase ("part of", "pull to open or close", ...): the canonical phrase of
        /// the relation id, or the phrase written in the sample for an id this build does not know.
        pub fn phrase(&self) -> &$a str {
            $crate::relation_phrase(self.relation_id()).unwrap_or_else(|| self.wire().phrase_str())
        }

        /// Confidence in [0, 1].
        pub fn confidence(&self) -> f32 {
            self.wire().confidence
        }
    };
}

/// `true` when `haystack` contains `needle`, ASCII letters compared without case.
pub(crate) fn contains_ignore_ascii_case(haystack: &str, needle: &str) -> bool {
    let (haystack, needle) = (haystack.as_bytes(), needle.as_bytes());
    needle.is_empty() || haystack.windows(needle.len()).any(|w| w.eq_ignore_ascii_case(needle))
}

pub(crate) use {edge_record_accessors, node_record_accessors};
