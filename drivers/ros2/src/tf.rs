//! [`TfBuffer`]: the transforms of ROS 2's `/tf` and `/tf_static` topics, kept over time, and
//! lookups of `target_from_source` through the frame tree at a stamp (what `tf2::BufferCore` does,
//! with the interpolation rules of the daemon's own pose input, `op3dsg_drivers::pose::PoseBuffer`).
//!
//! - A `TransformStamped` is `parent_from_child` (`header.frame_id` is the parent). Each frame has
//!   at most one parent at a time, so the frames form trees.
//! - `/tf_static` transforms hold forever; a newer one for the same child replaces it (parent
//!   included). `/tf` transforms are kept per child frame for [`TfConfig::window_ns`] before that
//!   frame's newest one; each sample records its parent.
//! - A frame is static or dynamic by its first transform; a transform of the other kind for it
//!   is refused ([`TfInsertError::KindConflict`]).
//! - **Re-parenting** (a child's `/tf` transforms name a new parent): as tf2's `TimeCache`, the
//!   parent is the one of the samples used at the stamp, so a lookup after the change goes through
//!   the new parent (the newest wins) and one before it through the old. Samples with different
//!   parents are never interpolated: between them, the earlier one holds (tf2 does the same) when
//!   the stamp is within [`TfConfig::max_interpolation_gap_ns`] of it.
//! - A lookup walks both frames up to their common ancestor. Per dynamic edge, a stamp between two
//!   samples at most `max_interpolation_gap_ns` apart gets the transform interpolated (linear
//!   translation, SLERP rotation); otherwise the nearest sample within
//!   [`TfConfig::hold_tolerance_ns`] is held; otherwise the lookup fails
//!   ([`TfError::Extrapolation`] before the oldest or after the newest sample, [`TfError::Gap`]
//!   between two too far apart). Nothing is extrapolated.
//! - Frame ids lose a leading `/` (as tf2 does). Stamps are nanoseconds on the frames' clock.
//! - Refused on insert ([`TfInsertError`]): empty frame ids, a frame its own parent, non-finite
//!   values, a quaternion whose norm is off 1 by more than 1e-3 (the pose input's rule), a bad
//!   stamp, a stamp already held for that frame (tf2's `TF_REPEATED_DATA`), one older than the
//!   window, the other kind, and frames beyond [`TfConfig::max_frames`].

use std::collections::{HashMap, VecDeque};

use crate::msg::geometry_msgs::TransformStamped;
use crate::msg::tf2_msgs::TFMessage;
use crate::rigid::RigidTransform;

/// How a [`TfBuffer`] keeps and answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TfConfig {
    /// `/tf` samples kept per frame: those at most this long (ns) before its newest one.
    pub window_ns: u64,
    /// Two samples at most this far apart (ns) are interpolated to a stamp between them.
    pub max_interpolation_gap_ns: u64,
    /// Otherwise the nearest sample is held when it is at most this far (ns) from the stamp.
    pub hold_tolerance_ns: u64,
    /// Frames known at most (transforms naming further frames are refused).
    pub max_frames: usize,
}

impl Default for TfConfig {
    /// tf2's 10 s cache; interpolation across 0.5 s; hold 50 ms; 10 000 frames.
    fn default() -> Self {
        Self {
            window_ns: 10_000_000_000,
            max_interpolation_gap_ns: 500_000_000,
            hold_tolerance_ns: 50_000_000,
            max_frames: 10_000,
        }
    }
}

/// Why a lookup has no transform.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TfError {
    /// No transform names this frame.
    #[error("frame {0:?} does not exist (no transform names it)")]
    FrameNotFound(String),
    /// The two frames are not connected at the stamp.
    #[error("no transform path from {from:?} to {to:?}: {missing_link}")]
    NoPath {
        /// The source frame.
        from: String,
        /// The target frame.
        to: String,
        /// Where the chain breaks: `odom has no parent`, `frames a and b are in different trees
        /// (roots x and y)`, or a loop.
        missing_link: String,
    },
    /// The stamp is before the oldest or after the newest sample of an edge by more than the hold
    /// tolerance.
    #[error(
        "{edge}: stamp {stamp_ns} ns is {} its samples ({oldest_ns}..={newest_ns} ns) by more than the hold tolerance",
        if stamp_ns > newest_ns { "after" } else { "before" }
    )]
    Extrapolation {
        /// `parent -> child`.
        edge: String,
        /// The stamp looked up.
        stamp_ns: u64,
        /// The edge's oldest sample.
        oldest_ns: u64,
        /// The edge's newest sample.
        newest_ns: u64,
    },
    /// The samples around the stamp are too far apart to interpolate and neither is within the
    /// hold tolerance.
    #[error(
        "{edge}: samples at {before_ns} and {after_ns} ns around stamp {stamp_ns} ns are too far apart to interpolate"
    )]
    Gap {
        /// `parent -> child`.
        edge: String,
        /// The stamp looked up.
        stamp_ns: u64,
        /// The sample before.
        before_ns: u64,
        /// The sample after.
        after_ns: u64,
    },
}

impl TfError {
    /// The stamp is after an edge's newest sample: a caller may wait for newer transforms.
    pub fn is_after_newest(&self) -> bool {
        matches!(self, Self::Extrapolation { stamp_ns, newest_ns, .. } if stamp_ns > newest_ns)
    }
}

/// Why a transform was not added.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TfInsertError {
    /// `header.frame_id` or `child_frame_id` is empty.
    #[error("transform with an empty {0} frame id")]
    EmptyFrameId(&'static str),
    /// A frame cannot be its own parent.
    #[error("transform from {0:?} to itself")]
    SelfTransform(String),
    /// NaN or infinite values.
    #[error("{edge}: non-finite translation or rotation")]
    NonFinite {
        /// `parent -> child`.
        edge: String,
    },
    /// The quaternion is not a rotation.
    #[error("{edge}: quaternion norm {norm} is off 1 by more than 1e-3")]
    NonUnitQuaternion {
        /// `parent -> child`.
        edge: String,
        /// Its norm.
        norm: f64,
    },
    /// Negative seconds or nanoseconds of a second or more.
    #[error("{edge}: stamp {sec} s {nanosec} ns is not a time after the epoch")]
    BadStamp {
        /// `parent -> child`.
        edge: String,
        /// Seconds.
        sec: i32,
        /// Nanoseconds.
        nanosec: u32,
    },
    /// A sample with this stamp is already held for the child (it is kept).
    #[error("{edge}: a transform stamped {stamp_ns} ns is already held (repeated data ignored)")]
    RepeatedStamp {
        /// `parent -> child`.
        edge: String,
        /// The stamp.
        stamp_ns: u64,
    },
    /// Older than the window before the child's newest sample.
    #[error("{edge}: stamp {stamp_ns} ns is older than the kept window (newest {newest_ns} ns)")]
    TooOld {
        /// `parent -> child`.
        edge: String,
        /// The stamp.
        stamp_ns: u64,
        /// The child's newest sample.
        newest_ns: u64,
    },
    /// The child comes from the other topic.
    #[error("frame {child:?} comes from {}; a {} transform for it is refused", if *now_static { "/tf" } else { "/tf_static" }, if *now_static { "/tf_static" } else { "/tf" })]
    KindConflict {
        /// The child frame.
        child: String,
        /// The refused transform was static.
        now_static: bool,
    },
    /// [`TfConfig::max_frames`] reached.
    #[error("{edge}: more than {max} frames")]
    TooManyFrames {
        /// `parent -> child`.
        edge: String,
        /// The limit.
        max: usize,
    },
}

type FrameId = usize;

#[derive(Debug, Clone, Copy)]
struct Sample {
    stamp_ns: u64,
    parent: FrameId,
    parent_from_child: RigidTransform,
}

#[derive(Debug, Clone)]
enum Link {
    /// A root (so far).
    None,
    Static {
        parent: FrameId,
        parent_from_child: RigidTransform,
    },
    /// Samples in stamp order, never empty.
    Dynamic(VecDeque<Sample>),
}

/// The frames of the last successful lookup, for health.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TfPath {
    /// From the source frame up to the common ancestor, then down to the target frame.
    pub frames: Vec<String>,
    /// The stamp looked up.
    pub stamp_ns: u64,
    /// The oldest of the newest samples of the path's `/tf` edges: how fresh the chain's data
    /// is (`None` when every edge is static).
    pub newest_data_ns: Option<u64>,
}

/// A resolved lookup.
#[derive(Debug, Clone, PartialEq)]
pub struct Resolved {
    /// `target_from_source`.
    pub target_from_source: RigidTransform,
    /// The path it went through.
    pub path: TfPath,
}

/// The transform tree over time (see the module docs).
#[derive(Debug, Clone)]
pub struct TfBuffer {
    config: TfConfig,
    ids: HashMap<String, FrameId>,
    names: Vec<String>,
    links: Vec<Link>,
    last_path: Option<TfPath>,
}

fn strip(frame: &str) -> &str {
    frame.strip_prefix('/').unwrap_or(frame)
}

impl TfBuffer {
    /// An empty buffer.
    pub fn new(config: TfConfig) -> Self {
        Self { config, ids: HashMap::new(), names: Vec::new(), links: Vec::new(), last_path: None }
    }

    /// The configuration in use.
    pub fn config(&self) -> &TfConfig {
        &self.config
    }

    /// Adds every transform of a message; the refused ones' reasons (empty: all added).
    pub fn insert_message(&mut self, message: &TFMessage, is_static: bool) -> Vec<TfInsertError> {
        message.transforms.iter().filter_map(|t| self.insert(t, is_static).err()).collect()
    }

    /// Adds one transform (`is_static`: it came on `/tf_static`).
    pub fn insert(&mut self, t: &TransformStamped, is_static: bool) -> Result<(), TfInsertError> {
        let (parent, child) = (strip(&t.header.frame_id), strip(&t.child_frame_id));
        if parent.is_empty() || child.is_empty() {
            return Err(TfInsertError::EmptyFrameId(if parent.is_empty() { "parent" } else { "child" }));
        }
        if parent == child {
            return Err(TfInsertError::SelfTransform(child.to_string()));
        }
        let edge = || format!("{parent} -> {child}");
        let (v, q) = (t.transform.translation, t.transform.rotation);
        if ![v.x, v.y, v.z, q.x, q.y, q.z, q.w].iter().all(|x| x.is_finite()) {
            return Err(TfInsertError::NonFinite { edge: edge() });
        }
        let norm = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
        if (norm - 1.0).abs() > 1e-3 {
            return Err(TfInsertError::NonUnitQuaternion { edge: edge(), norm });
        }
        let stamp = t.header.stamp;
        let stamp_ns = match (is_static, stamp.to_ns()) {
            (true, _) => 0,
            (false, Some(ns)) => ns,
            (false, None) => {
                return Err(TfInsertError::BadStamp { edge: edge(), sec: stamp.sec, nanosec: stamp.nanosec });
            }
        };
        let new_frames = usize::from(!self.ids.contains_key(parent)) + usize::from(!self.ids.contains_key(child));
        if self.names.len() + new_frames > self.config.max_frames {
            return Err(TfInsertError::TooManyFrames { edge: edge(), max: self.config.max_frames });
        }
        // Check the child's kind before creating any frame.
        if let Some(&c) = self.ids.get(child) {
            match (&self.links[c], is_static) {
                (Link::Static { .. }, false) | (Link::Dynamic(_), true) => {
                    return Err(TfInsertError::KindConflict { child: child.to_string(), now_static: is_static });
                }
                _ => {}
            }
        }
        let parent_from_child = RigidTransform::from(t.transform);
        let (p, c) = (self.intern(parent), self.intern(child));
        if is_static {
            self.links[c] = Link::Static { parent: p, parent_from_child };
            return Ok(());
        }
        let sample = Sample { stamp_ns, parent: p, parent_from_child };
        let window_ns = self.config.window_ns;
        let samples = match &mut self.links[c] {
            Link::Dynamic(samples) => samples,
            link => {
                *link = Link::Dynamic(VecDeque::from([sample]));
                return Ok(());
            }
        };
        let newest_ns = samples.back().map_or(stamp_ns, |s| s.stamp_ns);
        if stamp_ns.saturating_add(window_ns) < newest_ns {
            return Err(TfInsertError::TooOld { edge: edge(), stamp_ns, newest_ns });
        }
        let at = samples.partition_point(|s| s.stamp_ns < stamp_ns);
        if samples.get(at).is_some_and(|s| s.stamp_ns == stamp_ns) {
            return Err(TfInsertError::RepeatedStamp { edge: edge(), stamp_ns });
        }
        samples.insert(at, sample);
        let newest_ns = newest_ns.max(stamp_ns);
        while samples.front().is_some_and(|s| s.stamp_ns.saturating_add(window_ns) < newest_ns) {
            samples.pop_front();
        }
        Ok(())
    }

    fn intern(&mut self, frame: &str) -> FrameId {
        if let Some(&id) = self.ids.get(frame) {
            return id;
        }
        let id = self.names.len();
        self.ids.insert(frame.to_string(), id);
        self.names.push(frame.to_string());
        self.links.push(Link::None);
        id
    }

    /// Forgets every `/tf` sample (after the frames' clock jumped back); static transforms stay.
    pub fn clear_dynamic(&mut self) {
        for link in &mut self.links {
            if matches!(link, Link::Dynamic(_)) {
                *link = Link::None;
            }
        }
        self.last_path = None;
    }

    /// Every frame named so far.
    pub fn frame_names(&self) -> impl Iterator<Item = &str> {
        self.names.iter().map(String::as_str)
    }

    /// The path of the last successful [`Self::lookup`].
    pub fn last_path(&self) -> Option<&TfPath> {
        self.last_path.as_ref()
    }

    /// `target_from_source` at `stamp_ns` (see the module docs); a success is kept as
    /// [`Self::last_path`].
    pub fn lookup(&mut self, target: &str, source: &str, stamp_ns: u64) -> Result<RigidTransform, TfError> {
        let resolved = self.resolve(target, source, stamp_ns)?;
        self.last_path = Some(resolved.path);
        Ok(resolved.target_from_source)
    }

    /// The newest stamp at which every `/tf` edge between the two frames has data (tf2's "latest
    /// common time", its lookups at time 0), taking each frame's newest parent; `None` when every
    /// edge on the way is static (any stamp will do).
    pub fn latest_common_stamp(&self, target: &str, source: &str) -> Result<Option<u64>, TfError> {
        let (tid, sid) = self.ids_of(target, source)?;
        let up = |mut f: FrameId| {
            let mut chain = vec![(f, None::<u64>)];
            while chain.len() <= self.names.len() {
                let (parent, newest) = match &self.links[f] {
                    Link::None => break,
                    Link::Static { parent, .. } => (*parent, None),
                    Link::Dynamic(s) => s.back().map_or((f, None), |s| (s.parent, Some(s.stamp_ns))),
                };
                chain.push((parent, newest));
                f = parent;
            }
            chain
        };
        let (from_source, from_target) = (up(sid), up(tid));
        let meet = from_source.iter().position(|(f, _)| from_target.iter().any(|(g, _)| g == f));
        let Some(k) = meet else {
            return Err(self.no_path(target, source, from_target.last().map(|c| c.0), from_source.last().map(|c| c.0)));
        };
        let common = from_source[k].0;
        let j = from_target.iter().position(|(g, _)| *g == common).unwrap_or(0);
        Ok(from_source[1..=k].iter().chain(&from_target[1..=j]).filter_map(|(_, newest)| *newest).min())
    }

    /// [`Self::lookup`] without recording the path.
    pub fn resolve(&self, target: &str, source: &str, stamp_ns: u64) -> Result<Resolved, TfError> {
        let (tid, sid) = self.ids_of(target, source)?;
        // Up from the source: (frame, frame_from_source, newest sample of the edge into it).
        let mut from_source = vec![(sid, RigidTransform::IDENTITY)];
        let mut newest: Vec<u64> = Vec::new();
        let mut first_error = None;
        let looped = |frames: &[(FrameId, RigidTransform)]| frames.len() > self.names.len();
        while let Some(&(f, f_from_source)) = from_source.last() {
            if f == tid {
                break;
            }
            if looped(&from_source) {
                first_error = Some(self.loop_error(target, source, f));
                break;
            }
            match self.parent_at(f, stamp_ns) {
                Ok(Some((p, p_from_f, n))) => {
                    from_source.push((p, p_from_f * f_from_source));
                    newest.extend(n);
                }
                Ok(None) => break,
                Err(e) => {
                    first_error = Some(e);
                    break;
                }
            }
        }
        // Up from the target until a frame of the source's chain.
        let mut from_target = vec![(tid, RigidTransform::IDENTITY)];
        let mut newest_target: Vec<u64> = Vec::new();
        loop {
            let &(g, g_from_target) = from_target.last().unwrap_or(&(tid, RigidTransform::IDENTITY));
            if let Some(k) = from_source.iter().position(|(f, _)| *f == g) {
                let common_from_source = from_source[k].1;
                let frames = from_source[..=k]
                    .iter()
                    .map(|(f, _)| *f)
                    .chain(from_target[..from_target.len() - 1].iter().rev().map(|(f, _)| *f))
                    .map(|f| self.names[f].clone())
                    .collect();
                // Only the source edges below the common ancestor count.
                newest.truncate(self.dynamic_edges_below(&from_source[..=k]));
                newest.extend(newest_target);
                return Ok(Resolved {
                    target_from_source: g_from_target.inverse() * common_from_source,
                    path: TfPath { frames, stamp_ns, newest_data_ns: newest.iter().copied().min() },
                });
            }
            if looped(&from_target) {
                return Err(first_error.unwrap_or_else(|| self.loop_error(target, source, g)));
            }
            match self.parent_at(g, stamp_ns) {
                Ok(Some((p, p_from_g, n))) => {
                    from_target.push((p, p_from_g * g_from_target));
                    newest_target.extend(n);
                }
                Ok(None) => {
                    let source_root = from_source.last().map(|c| c.0);
                    return Err(first_error.unwrap_or_else(|| self.no_path(target, source, Some(g), source_root)));
                }
                Err(e) => return Err(first_error.unwrap_or(e)),
            }
        }
    }

    fn ids_of(&self, target: &str, source: &str) -> Result<(FrameId, FrameId), TfError> {
        let id =
            |frame: &str| self.ids.get(strip(frame)).copied().ok_or_else(|| TfError::FrameNotFound(frame.to_string()));
        let sid = id(source)?;
        Ok((id(target)?, sid))
    }

    /// How many of the edges into `chain[1..]` are dynamic.
    fn dynamic_edges_below(&self, chain: &[(FrameId, RigidTransform)]) -> usize {
        chain[..chain.len().saturating_sub(1)]
            .iter()
            .filter(|(f, _)| matches!(self.links[*f], Link::Dynamic(_)))
            .count()
    }

    fn loop_error(&self, target: &str, source: &str, at: FrameId) -> TfError {
        TfError::NoPath {
            from: source.to_string(),
            to: target.to_string(),
            missing_link: format!("the parents of {} form a loop", self.names[at]),
        }
    }

    fn no_path(
        &self,
        target: &str,
        source: &str,
        target_root: Option<FrameId>,
        source_root: Option<FrameId>,
    ) -> TfError {
        let name = |f: Option<FrameId>| f.map_or("?", |f| self.names[f].as_str());
        let (t_root, s_root) = (name(target_root), name(source_root));
        let missing_link = if t_root == strip(target) {
            format!("{s_root} has no parent")
        } else if s_root == strip(source) {
            format!("{t_root} has no parent")
        } else {
            format!("frames {source} and {target} are in different trees (roots {s_root} and {t_root})")
        };
        TfError::NoPath { from: source.to_string(), to: target.to_string(), missing_link }
    }

    /// The parent of `f` at `stamp_ns`, `parent_from_f`, and the newest sample of a dynamic edge;
    /// `None` for a root.
    fn parent_at(&self, f: FrameId, stamp_ns: u64) -> Result<Option<(FrameId, RigidTransform, Option<u64>)>, TfError> {
        let samples = match &self.links[f] {
            Link::None => return Ok(None),
            Link::Static { parent, parent_from_child } => return Ok(Some((*parent, *parent_from_child, None))),
            Link::Dynamic(samples) => samples,
        };
        let (Some(oldest), Some(newest)) = (samples.front(), samples.back()) else {
            return Ok(None);
        };
        let edge = |s: &Sample| format!("{} -> {}", self.names[s.parent], self.names[f]);
        let found = |s: &Sample, t: RigidTransform| Ok(Some((s.parent, t, Some(newest.stamp_ns))));
        let after = samples.partition_point(|s| s.stamp_ns < stamp_ns);
        let (prev, next) = (after.checked_sub(1).map(|i| &samples[i]), samples.get(after));
        let (gap, hold) = (self.config.max_interpolation_gap_ns, self.config.hold_tolerance_ns);
        match (prev, next) {
            (_, Some(n)) if n.stamp_ns == stamp_ns => found(n, n.parent_from_child),
            (Some(p), Some(n)) => {
                let (to_prev, to_next) = (stamp_ns - p.stamp_ns, n.stamp_ns - stamp_ns);
                if p.parent == n.parent && n.stamp_ns - p.stamp_ns <= gap {
                    let t = to_prev as f64 / (n.stamp_ns - p.stamp_ns) as f64;
                    found(p, p.parent_from_child.interpolate(&n.parent_from_child, t))
                } else if p.parent != n.parent && to_prev <= gap {
                    found(p, p.parent_from_child)
                } else if to_prev.min(to_next) <= hold {
                    let nearest = if to_prev <= to_next { p } else { n };
                    found(nearest, nearest.parent_from_child)
                } else {
                    Err(TfError::Gap { edge: edge(p), stamp_ns, before_ns: p.stamp_ns, after_ns: n.stamp_ns })
                }
            }
            (Some(p), None) if stamp_ns - p.stamp_ns <= hold => found(p, p.parent_from_child),
            (None, Some(n)) if n.stamp_ns - stamp_ns <= hold => found(n, n.parent_from_child),
            (Some(s), None) | (None, Some(s)) => Err(TfError::Extrapolation {
                edge: edge(s),
                stamp_ns,
                oldest_ns: oldest.stamp_ns,
                newest_ns: newest.stamp_ns,
            }),
            (None, None) => Ok(None),
        }
    }
}
