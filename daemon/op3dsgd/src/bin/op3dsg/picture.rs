//! The graph as a picture for `op3dsg dump`: Graphviz DOT (`--format dot`, for `dot -Tsvg`,
//! `xdot` or any Graphviz viewer) and SVG drawn without Graphviz (`--format svg`, laid out by the
//! pure-Rust `layout-rs`).
//!
//! Both draw the same [`Picture`]: objects as boxes, parts as ellipses in another colour, each
//! labelled with its label and `#id`; every relation an arrow from source to target labelled with
//! its phrase, in one style per family: part-of (dashed grey), spatial (blue), functional (bold
//! red). Edges to a node outside the sample (a graph whose map exceeded the sample's capacity)
//! are left out, and the DOT output says how many in a comment.

use std::collections::BTreeSet;
use std::fmt::Write as _;

use layout::backends::svg::SVGWriter;
use layout::core::base::Orientation;
use layout::core::color::Color;
use layout::core::style::{LineStyleKind, StyleAttr};
use layout::std_shapes::render::get_shape_size;
use layout::std_shapes::shapes::{Arrow, Element, LineEndKind, ShapeKind};
use layout::topo::layout::VisualGraph;
use op3dsg_ipc_types::{EdgeKind, Graph};

/// The family of a relation, which decides how its edge is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Family {
    /// A part's `part of` edge to its object.
    PartOf,
    /// The other spatial relations (`on`, `next to`, ...).
    Spatial,
    /// Functional relations (the source acts on the target).
    Functional,
}

impl Family {
    /// The name the DOT and SVG outputs give it (`class` attribute).
    fn name(self) -> &'static str {
        match self {
            Self::PartOf => "part-of",
            Self::Spatial => "spatial",
            Self::Functional => "functional",
        }
    }

    /// Line colour, `#rrggbb`.
    fn colour(self) -> &'static str {
        match self {
            Self::PartOf => "#808080",
            Self::Spatial => "#3465a4",
            Self::Functional => "#cc0000",
        }
    }
}

/// One node of the picture.
#[derive(Debug)]
struct Shape {
    id: u32,
    /// The node's label, then its id on a second line.
    text: String,
    part: bool,
}

/// One edge of the picture.
#[derive(Debug)]
struct Link {
    source: u32,
    target: u32,
    phrase: String,
    family: Family,
}

/// What both outputs draw.
#[derive(Debug)]
struct Picture {
    /// The graph's version, source and frame, as the picture's caption.
    caption: String,
    shapes: Vec<Shape>,
    links: Vec<Link>,
    /// Edges left out: one end is not in this sample.
    left_out: usize,
}

/// Fill colours of objects and of parts.
const OBJECT_FILL: &str = "#dbe8f7";
const PART_FILL: &str = "#fde9c9";

impl Picture {
    fn of(graph: &Graph) -> Self {
        let shapes: Vec<Shape> = graph
            .nodes()
            .map(|n| Shape { id: n.id(), text: format!("{}\n#{}", n.label(), n.id()), part: n.is_part() })
            .collect();
        let present: BTreeSet<u32> = shapes.iter().map(|s| s.id).collect();
        let mut links = Vec::new();
        let mut left_out = 0;
        for e in graph.edges() {
            if !present.contains(&e.source_id()) || !present.contains(&e.target_id()) {
                left_out += 1;
                continue;
            }
            let family = match e.kind() {
                EdgeKind::Functional => Family::Functional,
                EdgeKind::Spatial if e.phrase() == "part of" => Family::PartOf,
                EdgeKind::Spatial => Family::Spatial,
            };
            links.push(Link { source: e.source_id(), target: e.target_id(), phrase: e.phrase().to_owned(), family });
        }
        let caption = format!(
            "op3dsg graph version {} ({}, frame {}): {} objects, {} parts, {} edges",
            graph.version(),
            graph.source_kind().as_str(),
            graph.world_frame(),
            graph.objects().count(),
            graph.parts().count(),
            links.len()
        );
        Self { caption, shapes, links, left_out }
    }
}

/// A DOT quoted string: `"` and `\` escaped, line breaks as `\n`.
fn quoted(text: &str) -> String {
    let mut s = String::with_capacity(text.len() + 2);
    s.push('"');
    for c in text.chars() {
        match c {
            '"' => s.push_str("\\\""),
            '\\' => s.push_str("\\\\"),
            '\n' => s.push_str("\\n"),
            '\r' => {}
            c => s.push(c),
        }
    }
    s.push('"');
    s
}

/// The graph in Graphviz DOT: one `digraph`, nodes `n<id>`, objects first in id order.
pub(super) fn dot(graph: &Graph) -> String {
    let picture = Picture::of(graph);
    let mut s = String::new();
    let _ = writeln!(s, "digraph op3dsg {{");
    let _ = writeln!(s, "  // {}", picture.caption);
    if picture.left_out > 0 {
        let _ = writeln!(s, "  // {} edges to nodes outside this sample left out", picture.left_out);
    }
    let _ =
        writeln!(s, "  graph [label={}, labelloc=t, rankdir=LR, fontname=\"Helvetica\"];", quoted(&picture.caption));
    let _ = writeln!(s, "  node [fontname=\"Helvetica\", style=filled];");
    let _ = writeln!(s, "  edge [fontname=\"Helvetica\", fontsize=10];");
    let (objects, parts): (Vec<&Shape>, Vec<&Shape>) = picture.shapes.iter().partition(|n| !n.part);
    for shape in objects.iter().chain(&parts) {
        let (kind, form, fill) =
            if shape.part { ("part", "ellipse", PART_FILL) } else { ("object", "box", OBJECT_FILL) };
        let _ = writeln!(
            s,
            "  n{} [label={}, shape={form}, fillcolor=\"{fill}\", class=\"{kind}\"];",
            shape.id,
            quoted(&shape.text)
        );
    }
    for link in &picture.links {
        let style = match link.family {
            Family::PartOf => "dashed",
            Family::Spatial => "solid",
            Family::Functional => "bold",
        };
        let colour = link.family.colour();
        let _ = writeln!(
            s,
            "  n{} -> n{} [label={}, style={style}, color=\"{colour}\", fontcolor=\"{colour}\", class=\"{}\"];",
            link.source,
            link.target,
            quoted(&link.phrase),
            link.family.name()
        );
    }
    let _ = writeln!(s, "}}");
    s
}

/// The graph as an SVG document, laid out and drawn by `layout-rs` (no Graphviz needed). Each
/// node is one `<g class="object|part" id="node-<id>">` holding its box or ellipse (the label
/// follows it as a `<text>`); each edge a `<g class="edge <family>">` holding its path.
pub(super) fn svg(graph: &Graph) -> String {
    let picture = Picture::of(graph);
    if picture.shapes.is_empty() {
        // The layout needs at least one node: an empty graph is its caption alone.
        return format!(
            "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"480\" \
             height=\"40\"><text x=\"10\" y=\"25\">{}</text></svg>\n",
            xml_text(&picture.caption)
        );
    }
    let direction = Orientation::LeftToRight;
    let mut visual = VisualGraph::new(direction);
    let mut handles = std::collections::BTreeMap::new();
    for shape in &picture.shapes {
        let (form, fill, kind) = if shape.part {
            (ShapeKind::new_circle(&shape.text), PART_FILL, "part")
        } else {
            (ShapeKind::new_box(&shape.text), OBJECT_FILL, "object")
        };
        let look = StyleAttr::new(Color::fast("black"), 1, Some(Color::fast(fill)), 0, 14);
        // The layout draws top to bottom within a rank of a left-to-right graph: shapes are sized
        // for the flipped orientation, as its own DOT reader does.
        let size = get_shape_size(direction.flip(), &form, 14, false);
        let properties = format!("class=\"{kind}\" id=\"node-{}\"", shape.id);
        handles.insert(
            shape.id,
            visual.add_node(Element::create_with_properties(form, look, direction.flip(), size, properties)),
        );
    }
    for link in &picture.links {
        let (Some(&from), Some(&to)) = (handles.get(&link.source), handles.get(&link.target)) else { continue };
        let width = if link.family == Family::Functional { 2 } else { 1 };
        let look = StyleAttr::new(Color::fast(link.family.colour()), width, None, 0, 11);
        let line = if link.family == Family::PartOf { LineStyleKind::Dashed } else { LineStyleKind::Normal };
        let arrow = Arrow::with_properties(
            LineEndKind::None,
            LineEndKind::Arrow,
            line,
            &link.phrase,
            &look,
            format!("class=\"edge {}\"", link.family.name()),
            &None,
            &None,
        );
        visual.add_edge(arrow, from, to);
    }
    let mut writer = SVGWriter::new();
    visual.do_it(false, false, false, &mut writer);
    let mut out = writer.finalize();
    out.push('\n');
    out
}

/// Text for an XML element: `&`, `<` and `>` escaped.
fn xml_text(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::publish::GraphBuffer;
    use op3dsg_ipc_types::{GraphHeader, NO_NODE, Node, SCHEMA_VERSION, write_fixed_str};

    use super::*;
    use crate::dump::tests::edge;

    fn node(id: u32, parent_id: u32, label: &str) -> Node {
        let mut n = Node { id, parent_id, kind: u8::from(parent_id != NO_NODE), ..Node::default() };
        write_fixed_str(&mut n.label, label);
        n
    }

    fn cabinet() -> Graph {
        let mut buffer = GraphBuffer::new();
        buffer.header = GraphHeader {
            schema_version: SCHEMA_VERSION,
            graph_version: 5,
            node_capacity: 16,
            edge_capacity: 16,
            ..GraphHeader::default()
        };
        let pull = op3dsg_ipc_types::FUNCTIONAL_RELATIONS[0];
        buffer.nodes = vec![node(1, NO_NODE, "cabinet \"A\""), node(2, 1, "handle"), node(3, NO_NODE, "floor")];
        buffer.edges = vec![
            edge(2, 1, false, "part of"),
            edge(2, 1, true, pull),
            edge(1, 3, false, "on"),
            // To a node this sample does not hold.
            edge(3, 99, false, "under"),
        ];
        Graph::from_message(&buffer.encode()).unwrap()
    }

    #[test]
    fn dot_draws_objects_and_parts_apart_and_labels_every_relation() {
        let text = dot(&cabinet());
        assert!(text.starts_with("digraph op3dsg {\n") && text.ends_with("}\n"), "{text}");
        assert!(text.contains("  n1 [label=\"cabinet \\\"A\\\"\\n#1\", shape=box,"), "quotes escaped: {text}");
        assert!(text.contains("  n2 [label=\"handle\\n#2\", shape=ellipse,"), "{text}");
        assert!(text.contains("  n2 -> n1 [label=\"part of\", style=dashed,"), "{text}");
        let pull = op3dsg_ipc_types::FUNCTIONAL_RELATIONS[0];
        assert!(text.contains(&format!("  n2 -> n1 [label=\"{pull}\", style=bold,")), "{text}");
        assert!(text.contains("  n1 -> n3 [label=\"on\", style=solid,"), "{text}");
        assert!(!text.contains("n99"), "no node invented for a missing end: {text}");
        assert!(text.contains("// 1 edges to nodes outside this sample left out"), "{text}");
        assert_eq!(text.matches(" -> ").count(), 3, "{text}");
    }

    #[test]
    fn svg_has_one_group_per_node_and_escapes_labels() {
        let text = svg(&cabinet());
        assert!(text.contains("<svg") && text.trim_end().ends_with("</svg>"), "{text}");
        assert_eq!(text.matches("class=\"object\"").count(), 2, "{text}");
        assert_eq!(text.matches("class=\"part\"").count(), 1, "{text}");
        assert!(text.contains("id=\"node-2\""), "{text}");
        assert!(text.contains("cabinet &quot;A&quot;"), "{text}");
        assert!(svg(&Graph::new()).contains("0 objects, 0 parts, 0 edges"));
    }
}
