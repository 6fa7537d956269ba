//! The cross-process suite: real op3dsgd, op3dsg and op3dsg-detectd processes, read the way
//! planners, Python clients, Zenoh and ROS 2 peers and systemd read them. One test binary (a
//! module per former file); cargo-nextest runs each test in its own process.

mod attach;
mod daemon_over_iceoryx2;
mod deb_package;
mod docs_commands;
mod dump_picture;
mod error_hygiene;
mod example_planner;
mod faults_llm;
mod faults_planner;
mod faults_replay;
mod full_configuration;
mod goal_service;
mod graph_view_live;
mod ipc_users;
mod live_view;
mod live_view_app;
mod pose_and_health;
mod pose_stream;
mod profile_errors;
mod query_service;
mod realsense_daemon;
mod record_daemon;
mod remote_common;
mod remote_detect;
mod remote_detect_link;
mod replay_daemon;
mod ros2_common;
mod ros2_out;
mod ros2_tf;
mod score_live_run;
mod service_contract;
mod service_notify;
mod service_snapshot;
mod text_encoder_startup;
mod watch_terminal;
mod zenoh_common;
mod zenoh_faults;
mod zenoh_remote;
