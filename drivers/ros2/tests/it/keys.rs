//! Key expressions and liveliness tokens against the examples of rmw_zenoh's `docs/design.md`
//! and the mapping of zenoh-bridge-ros2dds (`ros2_name_to_key_expr`).

use op3dsg_ros2::RosMessage;
use op3dsg_ros2::attachment::Attachment;
use op3dsg_ros2::keys::*;
use op3dsg_ros2::msg::{std_msgs, tf2_msgs};

const STRING_HASH: &str = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18";

#[test]
fn rmw_zenoh_topic_keys_match_the_design_examples() {
    let ty = std_msgs::String::TYPE;
    assert_eq!(
        rmw_zenoh_key(0, "/chatter", &ty, Distro::JazzyOrLater),
        format!("0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    );
    let fq = fully_qualified_topic("/robot1", "chatter").unwrap();
    assert_eq!(fq, "/robot1/chatter");
    assert_eq!(
        rmw_zenoh_key(0, &fq, &ty, Distro::JazzyOrLater),
        format!("0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    );
    // Humble: no type hash.
    assert_eq!(
        rmw_zenoh_key(3, "/tf", &tf2_msgs::TFMessage::TYPE, Distro::Humble),
        "3/tf/tf2_msgs::msg::dds_::TFMessage_/TypeHashNotSupported"
    );
    assert_eq!(
        rmw_zenoh_subscribe_key(0, "/tf_static", &tf2_msgs::TFMessage::TYPE),
        "0/tf_static/tf2_msgs::msg::dds_::TFMessage_/*"
    );
}

#[test]
fn names_resolve_as_in_ros() {
    assert_eq!(fully_qualified_topic("/robot1", "/tf").unwrap(), "/tf", "absolute names ignore the namespace");
    assert_eq!(fully_qualified_topic("", "tf").unwrap(), "/tf");
    assert_eq!(fully_qualified_topic("robot1/", "tf").unwrap(), "/robot1/tf");
    assert_eq!(normalize_namespace("/").unwrap(), "/");
    for (ns, topic, needle) in [
        ("/", "", "empty"),
        ("/", "/tf/", "empty part"),
        ("/", "a//b", "empty part"),
        ("/", "~/tf", "private"),
        ("/", "{node}/tf", "substitution"),
        ("/", "/9tf", "starts with a digit"),
        ("/", "/t f", "only letters"),
        ("/ro bot", "tf", "only letters"),
    ] {
        let err = fully_qualified_topic(ns, topic).unwrap_err().to_string();
        assert!(err.contains(needle), "{ns:?} {topic:?}: {err}");
    }
    assert_eq!("rmw_zenoh".parse::<KeyStyle>().unwrap(), KeyStyle::RmwZenoh);
    assert!("zenoh".parse::<KeyStyle>().unwrap_err().to_string().contains("\"zenoh\""));
    assert_eq!("kilted".parse::<Distro>().unwrap(), Distro::JazzyOrLater);
    assert!("iron".parse::<Distro>().is_err());
}

#[test]
fn bridge_keys_drop_the_slash_under_the_bridge_namespace() {
    assert_eq!(bridge_key("", "/tf").unwrap(), "tf");
    assert_eq!(bridge_key("/", "/tf_static").unwrap(), "tf_static");
    assert_eq!(bridge_key("/robot1", "/tf").unwrap(), "robot1/tf");
    assert_eq!(bridge_key("robot1", "/op3dsg/markers").unwrap(), "robot1/op3dsg/markers");
    let ty = tf2_msgs::TFMessage::TYPE;
    let keys = topic_keys(KeyStyle::Bridge, 0, "/bot", "tf", &ty, Distro::Humble).unwrap();
    assert_eq!((keys.fq_topic.as_str(), keys.publish.as_str(), keys.subscribe.as_str()), ("/tf", "bot/tf", "bot/tf"));
    let keys = topic_keys(KeyStyle::RmwZenoh, 7, "/bot", "tf", &ty, Distro::Humble).unwrap();
    assert_eq!(keys.fq_topic, "/bot/tf");
    assert_eq!(keys.publish, "7/bot/tf/tf2_msgs::msg::dds_::TFMessage_/TypeHashNotSupported");
    assert_eq!(keys.subscribe, "7/bot/tf/tf2_msgs::msg::dds_::TFMessage_/*");
}

#[test]
fn bridge_route_tokens_follow_the_bridge_format() {
    use op3dsg_ros2::msg::visualization_msgs::MarkerArray;
    let ty = MarkerArray::TYPE;
    assert_eq!(
        bridge_publisher_token("1f2e", "robot1/op3dsg/markers", &ty, Distro::JazzyOrLater, &Qos::DEFAULT),
        format!(
            "@/1f2e/@ros2_lv/MP/robot1§op3dsg§markers/visualization_msgs§msg§MarkerArray/:1:0:0,10:typehash={};",
            ty.rihs01
        )
    );
    assert_eq!(
        bridge_publisher_token("1f2e", "tf_static", &tf2_msgs::TFMessage::TYPE, Distro::Humble, &Qos::TF_STATIC),
        "@/1f2e/@ros2_lv/MP/tf_static/tf2_msgs§msg§TFMessage/:1:1:0,1"
    );
}

#[test]
fn liveliness_tokens_match_the_design_examples() {
    let listener = NodeIdentity::new(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "listener").unwrap();
    assert_eq!(listener.node_token(), "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener");
    let ty = std_msgs::String::TYPE;
    let qos10 = Qos { depth: 10, ..Qos::DEFAULT };
    assert_eq!(
        listener.endpoint_token(10, EntityKind::Subscription, "/chatter", &ty, Distro::JazzyOrLater, &qos10),
        format!(
            "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,"
        )
    );
    let talker = NodeIdentity::new(2, "8b20917502ee955ac4476e0266340d5c", 0, "", "talker").unwrap();
    let qos7 = Qos { depth: 7, ..Qos::DEFAULT };
    assert_eq!(
        talker.endpoint_token(10, EntityKind::Publisher, "/chatter", &ty, Distro::JazzyOrLater, &qos7),
        format!(
            "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,"
        )
    );
    // A namespaced node publishing /tf_static on Humble.
    let node = NodeIdentity::new(0, "1f", 3, "/robot1", "op3dsgd").unwrap();
    assert_eq!(
        node.endpoint_token(
            4,
            EntityKind::Publisher,
            "/robot1/tf_static",
            &tf2_msgs::TFMessage::TYPE,
            Distro::Humble,
            &Qos::TF_STATIC
        ),
        "@ros2_lv/0/1f/3/4/MP/%/%robot1/op3dsgd/%robot1%tf_static/tf2_msgs::msg::dds_::TFMessage_/TypeHashNotSupported/:1:,1:,:,:,,"
    );
    assert_eq!(Qos::TF.to_keyexpr(), "::,100:,:,:,,");
    let best_effort = Qos { reliability: Reliability::BestEffort, depth: 42, ..Qos::DEFAULT };
    assert_eq!(best_effort.to_keyexpr(), "2::,:,:,:,,");
    assert_eq!(liveliness_subscribe_key(5), "@ros2_lv/5/**");
    assert!(NodeIdentity::new(0, "AB", 0, "/", "n").is_err());
    assert!(NodeIdentity::new(0, "ab", 0, "/", "1n").is_err());
    assert!(NodeIdentity::new(0, "ab", 0, "/", "a/b").is_err());
}

/// XXH3-128 test vector of the empty input (xxHash's `sanity_test_vectors.h`): 0x99AA06D3014798D8
/// 6001C324468D497F, so the GID is the low half's little-endian bytes, then the high half's.
#[test]
fn gid_is_xxh3_128_low_half_first() {
    let gid = gid_of_token("");
    assert_eq!(&gid[..8], &0x6001C324468D497Fu64.to_le_bytes());
    assert_eq!(&gid[8..], &0x99AA06D3014798D8u64.to_le_bytes());
    let token = "@ros2_lv/0/1f/0/1/MP/%/%/n/%tf/tf2_msgs::msg::dds_::TFMessage_/TypeHashNotSupported/::,100:,:,:,,";
    assert_ne!(gid_of_token(token), gid);
    let attachment = Attachment { sequence_number: 1, source_timestamp_ns: 5, source_gid: gid_of_token(token) };
    assert_eq!(Attachment::decode(&attachment.encode()), Ok(attachment));
}
