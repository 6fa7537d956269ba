//! The live view's own messages, in the `foxglove` crate's generated types (protobuf on the
//! wire): the occupancy map as a `foxglove.Grid`, the downscaled images as `foxglove.RawImage`.
//! The scene and the camera's transform are the recorder's ([`crate::record::scene`]), so a
//! recording and the live view show the same messages.

use foxglove::bytes::Bytes;
use foxglove::messages::{Grid, PackedElementField, RawImage, Vector2, packed_element_field};
use op3dsg_drivers::mcap::messages::timestamp;

use crate::flow::LiveImages;
use crate::occupancy::MapCopy;
use crate::record::scene::pose;

/// The occupancy map as a `foxglove.Grid` in `world_frame`: one `int8` field `occupancy` per
/// cell (-1 unknown, else 0 free to 100 occupied), row-major, row 0 at the origin; the grid's
/// corner on the floor, its rows and columns along the world's horizontal axes.
pub fn occupancy_grid(map: &MapCopy, world_frame: &str) -> Grid {
    let h = &map.header;
    let (corner, rotation) = map.corner_pose();
    let cell = f64::from(h.cell_size_m);
    Grid {
        timestamp: Some(timestamp(h.stamp_ns)),
        frame_id: world_frame.to_owned(),
        pose: pose(corner.to_array(), rotation),
        column_count: h.width_cells,
        cell_size: Some(Vector2 { x: cell, y: cell }),
        row_stride: h.width_cells,
        cell_stride: 1,
        fields: vec![PackedElementField {
            name: "occupancy".to_owned(),
            offset: 0,
            r#type: packed_element_field::NumericType::Int8 as i32,
        }],
        data: Bytes::copy_from_slice(bytemuck::cast_slice(&map.cells)),
    }
}

/// The downscaled colour (`rgb8`) and depth (`16UC1`, the frame's depth units) as
/// `foxglove.RawImage`s in `camera_frame`; `None` for an image the frame did not have.
pub fn raw_images(images: &LiveImages, camera_frame: &str) -> (Option<RawImage>, Option<RawImage>) {
    let image = |encoding: &str, bytes_per_pixel: u32, data: &[u8]| RawImage {
        timestamp: Some(timestamp(images.stamp_ns)),
        frame_id: camera_frame.to_owned(),
        width: images.width,
        height: images.height,
        encoding: encoding.to_owned(),
        step: images.width * bytes_per_pixel,
        data: Bytes::copy_from_slice(data),
    };
    let colour = (!images.rgb.is_empty()).then(|| image("rgb8", 3, &images.rgb));
    let depth = (!images.depth.is_empty()).then(|| image("16UC1", 2, bytemuck::cast_slice(&images.depth)));
    (colour, depth)
}
