//! What a detector hands to fusion: a label, a kind, a score and a mask per detection.

use op3dsg_ipc_types::NodeKind;

/// A binary mask over the detection's pixel box.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mask {
    /// Left column of the box (inclusive), pixels.
    pub x0: u32,
    /// Top row of the box (inclusive), pixels.
    pub y0: u32,
    /// Box width, pixels.
    pub width: u32,
    /// Box height, pixels.
    pub height: u32,
    /// Row-major, `width * height` entries, 1 = inside.
    pub data: Vec<u8>,
}

impl Mask {
    /// Number of pixels inside.
    pub fn area(&self) -> usize {
        self.data.iter().filter(|v| **v != 0).count()
    }

    /// Whether image pixel `(x, y)` is inside.
    #[inline]
    pub fn contains(&self, x: u32, y: u32) -> bool {
        x >= self.x0
            && y >= self.y0
            && x < self.x0 + self.width
            && y < self.y0 + self.height
            && self.data[((y - self.y0) * self.width + (x - self.x0)) as usize] != 0
    }

    /// Image pixel indices (row-major over a `image_width`-wide image) inside the mask.
    pub fn pixel_indices(&self, image_width: u32) -> impl Iterator<Item = usize> + '_ {
        (0..self.height).flat_map(move |row| {
            (0..self.width).filter_map(move |col| {
                (self.data[(row * self.width + col) as usize] != 0)
                    .then_some(((self.y0 + row) * image_width + self.x0 + col) as usize)
            })
        })
    }
}

/// One detected instance in one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Label as the detector names it (may be a synonym of the canonical label).
    pub label: String,
    /// Object or part.
    pub kind: NodeKind,
    /// Detector score in [0, 1].
    pub score: f32,
    /// Segmentation mask (its box is the detection box).
    pub mask: Mask,
    /// L2-normalised semantic feature when the detector provides one.
    pub semantic_feature: Option<Vec<f32>>,
}
