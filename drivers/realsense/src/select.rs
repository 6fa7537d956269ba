//! Which connected camera `[source.realsense]` opens, decided over what librealsense reports of
//! each camera (its name, e.g. `Intel RealSense D435I`, and its serial number), so the rule is
//! tested without a camera:
//!
//! 1. `serial` set: the camera with that serial, whatever `product` says (a warning when the
//!    two disagree); none with it is an error listing the cameras seen.
//! 2. Otherwise the cameras whose name matches `product` ([`product_matches`]; empty: every
//!    camera). Several: the first, with a warning naming them all (set `serial` to choose).
//!    None: an error listing the cameras seen, name and serial.
//!
//! On a Stretch 3 the head's D435i and the gripper's D405 are both connected; the Stretch
//! profile's `product = "D435I"` opens the head camera, never the D405.

/// One connected camera as librealsense names it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CameraId {
    /// `RS2_CAMERA_INFO_NAME`, e.g. `Intel RealSense D435I`.
    pub name: String,
    /// `RS2_CAMERA_INFO_SERIAL_NUMBER`.
    pub serial: String,
}

impl std::fmt::Display for CameraId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let name = if self.name.is_empty() { "a camera without a name" } else { &self.name };
        let serial = if self.serial.is_empty() { "none" } else { &self.serial };
        write!(f, "{name} (serial {serial})")
    }
}

/// The camera chosen: its index in the list given, and a warning to log when the choice was not
/// unambiguous (several cameras matched; `serial` picked one `product` does not name).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Choice {
    /// Index into the cameras passed to [`choose_camera`].
    pub index: usize,
    /// Why the choice deserves a look, if it does.
    pub warning: Option<String>,
}

/// Whether a camera called `name` is a `product`: compared without regard to case, `product`
/// is the whole name or one of its words (`D435I`, `d435i` and `Intel RealSense D435I` match
/// `Intel RealSense D435I`; `D435` does not, nor does `D405`). An empty `product` matches every
/// camera.
pub fn product_matches(product: &str, name: &str) -> bool {
    let product = product.trim();
    product.is_empty()
        || name.trim().eq_ignore_ascii_case(product)
        || name.split_whitespace().any(|word| word.eq_ignore_ascii_case(product))
}

fn listed(cameras: &[CameraId]) -> String {
    cameras.iter().map(ToString::to_string).collect::<Vec<_>>().join(", ")
}

/// Chooses the camera to open among `cameras` (in librealsense's order) by the profile's
/// `product` and `serial` (module docs). An error says why, naming every camera seen.
pub fn choose_camera(cameras: &[CameraId], product: &str, serial: &str) -> Result<Choice, String> {
    if cameras.is_empty() {
        return Err("no RealSense camera connected (check the USB cable, `rs-enumerate-devices`, and the udev rules)"
            .to_owned());
    }
    let product = product.trim();
    if !serial.is_empty() {
        let Some(index) = cameras.iter().position(|c| c.serial == serial) else {
            return Err(format!(
                "no RealSense camera with serial {serial:?} (source.realsense.serial); connected: {}",
                listed(cameras)
            ));
        };
        let warning = (!product_matches(product, &cameras[index].name)).then(|| {
            format!(
                "source.realsense.serial {serial:?} is {}, not a {product}: opening it, the serial wins over source.realsense.product",
                cameras[index].name
            )
        });
        return Ok(Choice { index, warning });
    }
    let matching: Vec<usize> = (0..cameras.len()).filter(|&i| product_matches(product, &cameras[i].name)).collect();
    match matching.as_slice() {
        [] => Err(format!(
            "no connected RealSense camera is a {product} (source.realsense.product); connected: {}",
            listed(cameras)
        )),
        [index] => Ok(Choice { index: *index, warning: None }),
        [first, ..] => {
            let what = if product.is_empty() { "RealSense cameras".to_owned() } else { format!("{product} cameras") };
            let names: Vec<CameraId> = matching.iter().map(|&i| cameras[i].clone()).collect();
            Ok(Choice {
                index: *first,
                warning: Some(format!(
                    "{} {what} connected: {}; opening the first, set source.realsense.serial to choose",
                    matching.len(),
                    listed(&names)
                )),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cameras(list: &[(&str, &str)]) -> Vec<CameraId> {
        list.iter().map(|(name, serial)| CameraId { name: (*name).to_owned(), serial: (*serial).to_owned() }).collect()
    }

    /// A Stretch 3: the gripper's D405 enumerated before the head's D435i.
    fn stretch() -> Vec<CameraId> {
        cameras(&[("Intel RealSense D405", "218622271111"), ("Intel RealSense D435I", "135322062222")])
    }

    #[test]
    fn the_product_is_a_word_of_the_name_or_the_name_in_any_case() {
        let name = "Intel RealSense D435I";
        for product in ["D435I", "d435i", " D435i ", "Intel RealSense D435I", "intel realsense d435i", ""] {
            assert!(product_matches(product, name), "{product:?}");
        }
        for product in ["D435", "D405", "435I", "RealSense D435", "D435I2"] {
            assert!(!product_matches(product, name), "{product:?}");
        }
    }

    #[test]
    fn product_d435i_opens_the_head_camera_and_never_the_gripper_d405() {
        let cams = stretch();
        assert_eq!(choose_camera(&cams, "D435I", ""), Ok(Choice { index: 1, warning: None }));
        let reversed: Vec<CameraId> = cams.iter().rev().cloned().collect();
        assert_eq!(choose_camera(&reversed, "d435i", ""), Ok(Choice { index: 0, warning: None }));
        let only_gripper = cameras(&[("Intel RealSense D405", "218622271111")]);
        assert_eq!(
            choose_camera(&only_gripper, "D435I", ""),
            Err("no connected RealSense camera is a D435I (source.realsense.product); connected: Intel RealSense D405 (serial 218622271111)".to_owned())
        );
    }

    #[test]
    fn the_serial_wins_and_says_so_when_the_product_disagrees() {
        let cams = stretch();
        assert_eq!(choose_camera(&cams, "D435I", "135322062222"), Ok(Choice { index: 1, warning: None }));
        assert_eq!(choose_camera(&cams, "", "218622271111"), Ok(Choice { index: 0, warning: None }));
        let choice = choose_camera(&cams, "D435I", "218622271111").expect("the serial is connected");
        assert_eq!(choice.index, 0);
        assert_eq!(
            choice.warning.as_deref(),
            Some(
                "source.realsense.serial \"218622271111\" is Intel RealSense D405, not a D435I: opening it, the serial wins over source.realsense.product"
            )
        );
        assert_eq!(
            choose_camera(&cams, "D435I", "999"),
            Err("no RealSense camera with serial \"999\" (source.realsense.serial); connected: Intel RealSense D405 (serial 218622271111), Intel RealSense D435I (serial 135322062222)".to_owned())
        );
    }

    #[test]
    fn several_matching_cameras_take_the_first_with_a_warning_naming_them() {
        let cams =
            cameras(&[("Intel RealSense D405", "1"), ("Intel RealSense D435I", "2"), ("Intel RealSense D435I", "3")]);
        let choice = choose_camera(&cams, "D435I", "").expect("two match");
        assert_eq!(choice.index, 1);
        assert_eq!(
            choice.warning.as_deref(),
            Some(
                "2 D435I cameras connected: Intel RealSense D435I (serial 2), Intel RealSense D435I (serial 3); opening the first, set source.realsense.serial to choose"
            )
        );
        // No product: every camera matches; one camera alone needs no warning.
        let choice = choose_camera(&cams, "", "").expect("any");
        assert_eq!(choice.index, 0);
        assert!(
            choice
                .warning
                .is_some_and(|w| w.starts_with("3 RealSense cameras connected: Intel RealSense D405 (serial 1), "))
        );
        assert_eq!(choose_camera(&cams[..1], "", ""), Ok(Choice { index: 0, warning: None }));
    }

    #[test]
    fn a_camera_without_name_or_serial_is_named_so() {
        let nameless = cameras(&[("", "")]);
        assert_eq!(
            choose_camera(&nameless, "D435I", ""),
            Err("no connected RealSense camera is a D435I (source.realsense.product); connected: a camera without a name (serial none)".to_owned())
        );
    }

    #[test]
    fn no_camera_at_all_says_what_to_check() {
        let err = choose_camera(&[], "D435I", "").expect_err("nothing connected");
        assert!(err.starts_with("no RealSense camera connected"), "{err}");
        assert_eq!(choose_camera(&[], "", "123"), Err(err));
    }
}
