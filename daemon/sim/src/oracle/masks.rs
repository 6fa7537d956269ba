//! Pixel work on the instance-id image: per-instance statistics ([`Stats`]), mask perturbations
//! ([`Morph`]), an instance's mask with erosion / dilation ([`instance_mask`]) and cropping a mask
//! to its tight box ([`tighten`]).

use op3dsg_runtime::perception::Mask;

/// Pixel statistics of one instance in the current frame.
#[derive(Debug, Clone, Copy)]
pub(super) struct Stats {
    pub(super) count: u32,
    pub(super) x0: u32,
    pub(super) y0: u32,
    pub(super) x1: u32,
    pub(super) y1: u32,
}

impl Stats {
    pub(super) const EMPTY: Stats = Stats { count: 0, x0: u32::MAX, y0: u32::MAX, x1: 0, y1: 0 };
}

/// What happens to a detection's mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Morph {
    Erode(u32),
    Dilate(u32),
}

/// The mask of instance `id` (pixel statistics `s`) in the `width` x `height` id image, eroded or
/// dilated by `morph` with a square structuring element, cropped to its tight box. Pixels beyond
/// the image edge do not erode (an instance cut by the border keeps its border pixels). `None`
/// when nothing is left.
pub(super) fn instance_mask(
    ids: &[u16],
    width: u32,
    height: u32,
    id: u16,
    s: Stats,
    morph: Option<Morph>,
) -> Option<Mask> {
    let radius = match morph {
        Some(Morph::Erode(r) | Morph::Dilate(r)) => r,
        None => 0,
    };
    // Region: the instance box grown by the radius, clipped to the image.
    let x0 = s.x0.saturating_sub(radius);
    let y0 = s.y0.saturating_sub(radius);
    let x1 = s.x1.saturating_add(radius).min(width - 1);
    let y1 = s.y1.saturating_add(radius).min(height - 1);
    let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
    let mut data = vec![0u8; (w * h) as usize];
    for y in y0..=y1 {
        let src = (y * width) as usize;
        let dst = ((y - y0) * w) as usize;
        for x in x0..=x1 {
            data[dst + (x - x0) as usize] = u8::from(ids[src + x as usize] == id);
        }
    }
    if radius > 0 {
        let dilate = matches!(morph, Some(Morph::Dilate(_)));
        // Windows are clipped to the region, which the image edge clips: out-of-image pixels are
        // neutral for both operations.
        data = filter_separable(&data, w as usize, h as usize, radius as usize, dilate);
    }
    tighten(Mask { x0, y0, width: w, height: h, data })
}

/// Square min (erosion) or max (dilation) filter of radius `r`, as a row pass then a column pass.
fn filter_separable(data: &[u8], w: usize, h: usize, r: usize, dilate: bool) -> Vec<u8> {
    let reduce = |window: &mut dyn Iterator<Item = u8>| -> u8 {
        if dilate { window.max().unwrap_or(0) } else { window.min().unwrap_or(0) }
    };
    let mut rows = vec![0u8; w * h];
    for y in 0..h {
        let line = &data[y * w..(y + 1) * w];
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = reduce(&mut line[a..=b].iter().copied());
        }
    }
    let mut out = vec![0u8; w * h];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            out[y * w + x] = reduce(&mut (a..=b).map(|yy| rows[yy * w + x]));
        }
    }
    out
}

/// Crops `mask` to the tight box of its inside pixels; `None` when it is empty.
pub(super) fn tighten(mask: Mask) -> Option<Mask> {
    let (w, h) = (mask.width as usize, mask.height as usize);
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for y in 0..h {
        for x in 0..w {
            if mask.data[y * w + x] != 0 {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
        }
    }
    if x0 == usize::MAX {
        return None;
    }
    if (x0, y0, x1, y1) == (0, 0, w - 1, h - 1) {
        return Some(mask);
    }
    let (nw, nh) = (x1 - x0 + 1, y1 - y0 + 1);
    let mut data = Vec::with_capacity(nw * nh);
    for y in y0..=y1 {
        data.extend_from_slice(&mask.data[y * w + x0..=y * w + x1]);
    }
    Some(Mask { x0: mask.x0 + x0 as u32, y0: mask.y0 + y0 as u32, width: nw as u32, height: nh as u32, data })
}
