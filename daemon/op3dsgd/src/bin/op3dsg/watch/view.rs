//! The full-screen view of `op3dsg watch`, drawn with ratatui: the graph (version, age, counts),
//! the daemon's counters, the per-stage table, the queues with their drops, the inputs and
//! subsystems (pose, tf, LLM refiner, snapshots, recorder), remote detection's workers (with
//! `detector.kind = "remote"`) and the last warnings. Drawing is a
//! function of what was received ([`View`]), so a test draws it on ratatui's `TestBackend`.

use std::time::Instant;

use op3dsg_ipc_types::Graph;
use op3dsg_runtime::ipc::{HealthReport, RemoteReport};
use ratatui::Frame;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style, Stylize};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Paragraph, Row, Table};

use super::warnings::Warnings;

/// What one frame of the view shows.
#[derive(Debug)]
pub(super) struct View<'a> {
    /// Where the feed reads from, in words.
    pub(super) source: &'a str,
    /// Whether the daemon was found.
    pub(super) connected: bool,
    /// The graph held.
    pub(super) graph: Option<&'a Graph>,
    /// The newest health record.
    pub(super) health: Option<&'a HealthReport>,
    /// The warnings derived so far.
    pub(super) warnings: &'a Warnings,
    /// Now, for the warnings' ages.
    pub(super) now: Instant,
    /// Now, nanoseconds since the Unix epoch, for the graph's age.
    pub(super) now_unix_ns: u64,
}

/// A duration in seconds, short: `0.4 s`, `12 s`, `3 min 5 s`, `2 h 10 min`.
fn short(seconds: f64) -> String {
    let s = seconds.max(0.0);
    if s < 10.0 {
        format!("{s:.1} s")
    } else if s < 60.0 {
        format!("{s:.0} s")
    } else if s < 3600.0 {
        format!("{} min {} s", (s / 60.0) as u64, s as u64 % 60)
    } else {
        format!("{} h {} min", (s / 3600.0) as u64, (s as u64 % 3600) / 60)
    }
}

fn label(text: &str) -> Span<'_> {
    Span::styled(text, Style::new().add_modifier(Modifier::BOLD))
}

fn alarm(text: String) -> Span<'static> {
    Span::styled(text, Style::new().fg(Color::Red).add_modifier(Modifier::BOLD))
}

/// Draws the whole view into the frame.
pub(super) fn draw(frame: &mut Frame<'_>, view: &View<'_>) {
    let rows = view.health.map_or(0, |h| h.stages.len().max(h.queues.len()));
    let remote = view.health.and_then(|h| h.remote.as_ref());
    let remote_rows = remote.map_or(0, |r| r.workers.len().max(1) as u16 + 3);
    let [top, tables, state, remote_area, warnings] = Layout::vertical([
        Constraint::Length(4),
        Constraint::Length(rows as u16 + 3),
        Constraint::Length(7),
        Constraint::Length(remote_rows),
        Constraint::Min(3),
    ])
    .areas(frame.area());
    frame.render_widget(header(view), top);
    let [stages, queues] = Layout::horizontal([Constraint::Percentage(58), Constraint::Percentage(42)]).areas(tables);
    draw_tables(frame, view.health, stages, queues);
    frame.render_widget(Paragraph::new(state_lines(view.health)).block(Block::bordered().title(" inputs ")), state);
    if let Some(r) = remote {
        frame.render_widget(remote_table(r), remote_area);
    }
    draw_warnings(frame, view, warnings);
}

/// Remote detection: a row per worker, the fallback's state in the title.
fn remote_table(r: &RemoteReport) -> Table<'static> {
    let head = Style::new().add_modifier(Modifier::BOLD);
    let title = if r.fallback_active {
        let active = alarm(format!("FALLBACK ACTIVE ({} keyframes) ", r.fallback_keyframes));
        Line::from(vec![" remote detection · ".into(), active])
    } else {
        Line::from(format!(" remote detection · fallback off ({} keyframes so far) ", r.fallback_keyframes))
    };
    let rows: Vec<Row<'static>> = if r.workers.is_empty() {
        vec![Row::new(["no worker seen yet"])]
    } else {
        r.workers
            .iter()
            .map(|w| {
                let rejected: u64 = w.rejections.values().sum();
                let flag = |n: u64| if n > 0 { n.to_string().yellow().bold() } else { "0".into() };
                Row::new(vec![
                    w.key.clone().into(),
                    if w.alive { "alive".into() } else { "GONE".red().bold() },
                    w.requests.to_string().into(),
                    w.replies.to_string().into(),
                    flag(w.timeouts),
                    flag(w.late),
                    flag(rejected),
                    w.in_flight.to_string().into(),
                    format!("{:.1}", w.round_trip_p50_ms).into(),
                    format!("{:.1}", w.round_trip_p99_ms).into(),
                    format!("{:.0}", w.bytes_per_keyframe as f64 / 1e3).into(),
                ])
            })
            .collect()
    };
    let widths = [
        Constraint::Min(16),
        Constraint::Length(6),
        Constraint::Length(9),
        Constraint::Length(9),
        Constraint::Length(8),
        Constraint::Length(6),
        Constraint::Length(9),
        Constraint::Length(6),
        Constraint::Length(8),
        Constraint::Length(8),
        Constraint::Length(8),
    ];
    let header = [
        "worker", "state", "requests", "replies", "timeouts", "late", "rejected", "busy", "rtt p50", "rtt p99", "kB/kf",
    ];
    Table::new(rows, widths).header(Row::new(header).style(head)).block(Block::bordered().title(title))
}

/// The title block: the graph and the daemon's counters.
fn header<'a>(view: &View<'a>) -> Paragraph<'a> {
    let title = Line::from(vec![" op3dsg watch ".bold(), Span::raw(format!("· {} ", view.source))]);
    let block = Block::bordered().title(title).title_top(Line::from(" q quits ").right_aligned());
    let graph = match view.graph {
        None if !view.connected => Line::from(format!("waiting for {}...", view.source).yellow()),
        None => Line::from("no graph yet"),
        Some(g) => {
            let age = if g.publish_time_ns() == 0 {
                String::new()
            } else {
                format!(", published {} ago", short(view.now_unix_ns.saturating_sub(g.publish_time_ns()) as f64 * 1e-9))
            };
            let mut spans = vec![
                label("graph "),
                Span::raw(format!("version {}{age}", g.version())),
                Span::raw(format!(
                    "   {} objects  {} parts  {} edges   {} in {}",
                    g.objects().count(),
                    g.parts().count(),
                    g.edge_count(),
                    g.source_kind().as_str(),
                    if g.world_frame().is_empty() { "?" } else { g.world_frame() }
                )),
            ];
            if g.capacity_exceeded() {
                spans.push(alarm("  CAPACITY EXCEEDED".into()));
            }
            Line::from(spans)
        }
    };
    let daemon = match view.health {
        None => Line::from("no health record yet"),
        Some(h) => {
            let source = if h.source_connected {
                Span::raw(format!("source {} connected", h.source_kind))
            } else {
                alarm(format!("source {} DISCONNECTED", h.source_kind))
            };
            Line::from(vec![
                label("daemon "),
                Span::raw(format!("up {}   ", short(h.uptime_s))),
                source,
                Span::raw(format!(
                    "   frames {}  keyframes {}  detections fused {}   planners {}   map {} nodes ({:.1} MiB)",
                    h.frames_captured,
                    h.keyframes,
                    h.detections_fused,
                    h.graph_subscribers,
                    h.map_node_count,
                    op3dsg_runtime::stats::mib(h.map_memory_bytes)
                )),
            ])
        }
    };
    Paragraph::new(vec![graph, daemon]).block(block)
}

/// The per-stage table and the queue table, side by side.
fn draw_tables(frame: &mut Frame<'_>, health: Option<&HealthReport>, stages: Rect, queues: Rect) {
    let head = Style::new().add_modifier(Modifier::BOLD | Modifier::UNDERLINED);
    let (stage_rows, queue_rows): (Vec<Row<'_>>, Vec<Row<'_>>) = match health {
        None => (Vec::new(), Vec::new()),
        Some(h) => (
            h.stages
                .iter()
                .map(|s| {
                    let errors = if s.errors > 0 { s.errors.to_string().red().bold() } else { "0".into() };
                    Row::new(vec![
                        s.name.clone().into(),
                        format!("{:.1}", s.rate_hz).into(),
                        format!("{:.1}", s.latency_p50_us / 1000.0).into(),
                        format!("{:.1}", s.latency_p99_us / 1000.0).into(),
                        errors,
                    ])
                })
                .collect(),
            h.queues
                .iter()
                .map(|q| {
                    let dropped = if q.dropped > 0 { q.dropped.to_string().yellow().bold() } else { "0".into() };
                    Row::new(vec![
                        q.name.clone().into(),
                        format!("{}/{}", q.depth, q.capacity).into(),
                        dropped,
                        q.pushed.to_string().into(),
                    ])
                })
                .collect(),
        ),
    };
    let widths = [
        Constraint::Min(10),
        Constraint::Length(8),
        Constraint::Length(8),
        Constraint::Length(8),
        Constraint::Length(7),
    ];
    let stage_table = Table::new(stage_rows, widths)
        .header(Row::new(["stage", "rate Hz", "p50 ms", "p99 ms", "errors"]).style(head))
        .block(Block::bordered().title(" stages "));
    frame.render_widget(stage_table, stages);
    let widths = [Constraint::Min(10), Constraint::Length(9), Constraint::Length(8), Constraint::Length(9)];
    let queue_table = Table::new(queue_rows, widths)
        .header(Row::new(["queue", "depth", "dropped", "pushed"]).style(head))
        .block(Block::bordered().title(" queues "));
    frame.render_widget(queue_table, queues);
}

/// One line each: the pose input, the tf input, the LLM refiner, the snapshots, the recorder.
fn state_lines(health: Option<&HealthReport>) -> Vec<Line<'static>> {
    let Some(h) = health else { return vec![Line::from("no health record yet")] };
    let accepted = h.poses.get("accepted").copied().unwrap_or(0);
    let refused: Vec<String> =
        h.poses.iter().filter(|(k, n)| *k != "accepted" && **n > 0).map(|(k, n)| format!("{k} {n}")).collect();
    let pose = if h.pose_source == "frame" {
        "not read (pose.source = \"frame\": each frame carries its pose)".to_owned()
    } else if accepted == 0 && refused.is_empty() {
        format!("none received   frames without a pose {}", h.frames_without_pose)
    } else {
        let refused = if refused.is_empty() { "none".to_owned() } else { refused.join(", ") };
        format!("accepted {accepted}  refused {refused}   frames without a pose {}", h.frames_without_pose)
    };
    let tf = match &h.tf {
        None => "off (pose.source is not ros2)".to_owned(),
        Some(tf) => {
            let age = tf.data_age_s.map_or_else(
                || if tf.path.is_empty() { String::new() } else { "  static chain".to_owned() },
                |age| format!("  data age {age:.3} s"),
            );
            format!(
                "{}{age}   /tf {}  /tf_static {}  refused {}  jumps back {}",
                if tf.path.is_empty() { "no lookup yet" } else { &tf.path },
                tf.dynamic_messages,
                tf.static_messages,
                tf.transforms_refused,
                tf.time_jumps
            )
        }
    };
    let r = &h.refiner;
    let llm = if r.state == "off" || r.state.is_empty() {
        "off".to_owned()
    } else {
        format!(
            "{}{}  calls {}  failures {} (last {})  accepted {}  rejected {}  last call {:.0} ms  graph version {}",
            r.state,
            if r.breaker_open { " (breaker open)" } else { "" },
            r.calls,
            r.failures,
            r.last_error,
            r.accepted,
            r.rejections.values().sum::<u64>(),
            f64::from(r.last_latency_us) / 1000.0,
            r.last_graph_version
        )
    };
    let snap = &h.snapshot;
    let snapshot = if snap.state == "off" || snap.state.is_empty() {
        "off".to_owned()
    } else {
        let now_ms =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64);
        let last = if snap.last_written_unix_ms == 0 {
            "none written yet".to_owned()
        } else {
            format!("last written {} ago", short(now_ms.saturating_sub(snap.last_written_unix_ms) as f64 / 1000.0))
        };
        format!(
            "{}  {last}  version {}  {:.1} KiB  written {}  failed {}  skipped {}",
            snap.state,
            snap.version,
            snap.last_bytes as f64 / 1024.0,
            snap.written,
            snap.failures,
            snap.skipped
        )
    };
    let rec = &h.recorder;
    let recorder = if rec.state == "off" || rec.state.is_empty() {
        "off".to_owned()
    } else {
        format!(
            "{}  files {}  written {}  dropped {}  {:.1} MiB",
            rec.state,
            rec.files,
            rec.messages_written,
            rec.messages_dropped,
            op3dsg_runtime::stats::mib(rec.bytes_written)
        )
    };
    [("pose      ", pose), ("tf        ", tf), ("llm       ", llm), ("snapshots ", snapshot), ("recorder  ", recorder)]
        .into_iter()
        .map(|(name, text)| Line::from(vec![Span::styled(name, Style::new().bold()), Span::raw(text)]))
        .collect()
}

/// The last warnings, newest first, as many as fit.
fn draw_warnings(frame: &mut Frame<'_>, view: &View<'_>, area: Rect) {
    let lines: Vec<Line<'_>> = view
        .warnings
        .recent()
        .take(usize::from(area.height.saturating_sub(2)))
        .map(|w| {
            let total = w.total.map_or_else(String::new, |n| format!(": {n}"));
            let ago = short(view.now.saturating_duration_since(w.at).as_secs_f64());
            Line::from(vec![Span::raw(format!("{ago:>10} ago  ")), format!("{}{total}", w.text).yellow()])
        })
        .collect();
    let lines = if lines.is_empty() { vec![Line::from("none")] } else { lines };
    let block = Block::bordered().title(" warnings (from the health records; details in the daemon's log) ");
    frame.render_widget(Paragraph::new(lines).block(block), area);
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::Health;
    use ratatui::Terminal;
    use ratatui::backend::TestBackend;

    use super::*;

    /// The screen's rows as text.
    fn screen(width: u16, height: u16, view: &View<'_>) -> Vec<String> {
        let mut terminal = Terminal::new(TestBackend::new(width, height)).unwrap();
        terminal.draw(|frame| draw(frame, view)).unwrap();
        let buffer = terminal.backend().buffer();
        (0..height).map(|y| (0..width).map(|x| buffer[(x, y)].symbol()).collect::<String>()).collect()
    }

    #[test]
    fn the_view_shows_the_stage_table_inputs_and_warnings_and_fits_any_size() {
        let mut health = Health { source_connected: 0, uptime_ns: 75_000_000_000, ..Health::default() };
        health.stage_count = 1;
        op3dsg_ipc_types::write_fixed_str(&mut health.stages[0].name, "fusion");
        (health.stages[0].rate_hz, health.stages[0].latency_p99_us, health.stages[0].errors) = (5.0, 12_300.0, 2);
        health.tf.active = 1;
        op3dsg_ipc_types::write_fixed_str(&mut health.tf.path, "map -> odom -> camera");
        let report = HealthReport::from(&health);
        let mut warnings = Warnings::default();
        warnings.observe(&report, Instant::now());
        let view = View {
            source: "op3dsgd under prefix test",
            connected: true,
            graph: None,
            health: Some(&report),
            warnings: &warnings,
            now: Instant::now(),
            now_unix_ns: 0,
        };
        let rows = screen(120, 30, &view);
        let text = rows.join("\n");
        assert!(text.contains("op3dsg watch · op3dsgd under prefix test"), "{text}");
        assert!(text.contains("no graph yet"), "{text}");
        assert!(text.contains("source unknown DISCONNECTED"), "{text}");
        assert!(text.contains("daemon up 1 min 15 s"), "{text}");
        let fusion = rows.iter().find(|r| r.contains("fusion ")).expect("a fusion row");
        assert_eq!(fusion.split_whitespace().filter(|c| c.parse::<f64>().is_ok()).count(), 4, "{fusion}");
        assert!(text.contains("rate Hz") && text.contains("p99 ms") && text.contains("12.3"), "{text}");
        assert!(text.contains("tf        map -> odom -> camera"), "{text}");
        assert!(text.contains("stage fusion errors: 2"), "{text}");
        // A small terminal: the same view clipped, never more rows than it has.
        assert_eq!(screen(40, 10, &view).len(), 10);
    }

    #[test]
    fn the_view_has_a_row_per_remote_worker_with_remote_detection() {
        let mut health = Health::default();
        health.remote.active = 1;
        health.remote.fallback_active = 1;
        health.remote.fallback_keyframes = 7;
        health.remote.worker_count = 2;
        for (i, w) in health.remote.workers[..2].iter_mut().enumerate() {
            op3dsg_ipc_types::write_fixed_str(&mut w.key, &format!("robot/op3dsg/detect/gpu{i}"));
            (w.requests, w.replies, w.timeouts, w.alive) = (40, 38, 2, u8::from(i == 0));
            w.round_trip_p50_us = 123_400.0;
        }
        let report = HealthReport::from(&health);
        let warnings = Warnings::default();
        let view = View {
            source: "test",
            connected: true,
            graph: None,
            health: Some(&report),
            warnings: &warnings,
            now: Instant::now(),
            now_unix_ns: 0,
        };
        let rows = screen(140, 40, &view);
        let text = rows.join("\n");
        assert!(text.contains("FALLBACK ACTIVE (7 keyframes)"), "{text}");
        let gpu1 = rows.iter().find(|r| r.contains("robot/op3dsg/detect/gpu1")).expect("a row for gpu1");
        assert!(gpu1.contains("GONE") && gpu1.contains("123.4"), "{gpu1}");
        assert!(rows.iter().any(|r| r.contains("robot/op3dsg/detect/gpu0") && r.contains("alive")), "{text}");
        // Without remote detection, no such table.
        let plain = HealthReport::from(&Health::default());
        let view = View { health: Some(&plain), ..view };
        assert!(!screen(140, 40, &view).join("\n").contains("remote detection"));
    }
}
