//! `op3dsg-layers report`: one table line per crate, sorted by crate name; with `verbose`, each
//! crate's circles and every arrow with the first place that writes it.

use std::fmt::Write;

use crate::cycles;
use crate::model::CrateModel;

/// The table (and, with `verbose`, the arrows), ending with a newline.
pub fn render(crates: &[CrateModel], verbose: bool) -> String {
    let header = ["crate", "rows", "modules", "arrows", "circles", "largest circle", "largest product file"];
    let mut table: Vec<[String; 7]> = vec![header.map(str::to_owned)];
    for krate in crates {
        let circles = circles(krate);
        let rows = krate.layers.as_ref().and_then(|l| l.rows.as_ref()).map_or("-".to_owned(), |r| r.len().to_string());
        let largest_file = krate
            .files
            .iter()
            .max_by(|a, b| a.lines.cmp(&b.lines).then_with(|| b.path.cmp(&a.path)))
            .map_or("-".to_owned(), |f| format!("{} ({} lines)", f.path, f.lines));
        table.push([
            krate.name.clone(),
            rows,
            krate.modules.len().to_string(),
            krate.arrows.len().to_string(),
            circles.len().to_string(),
            circles.iter().map(Vec::len).max().unwrap_or(0).to_string(),
            largest_file,
        ]);
    }
    let widths: Vec<usize> = (0..header.len()).map(|c| table.iter().map(|r| r[c].len()).max().unwrap_or(0)).collect();
    let mut out = String::new();
    for row in &table {
        let mut line = format!("{:<w$}", row[0], w = widths[0]);
        for (cell, width) in row[1..6].iter().zip(&widths[1..6]) {
            let _ = write!(line, "  {cell:>width$}");
        }
        let _ = write!(line, "  {}", row[6]);
        out.push_str(line.trim_end());
        out.push('\n');
    }
    if verbose {
        for krate in crates.iter().filter(|k| !k.arrows.is_empty()) {
            let _ = writeln!(out, "\n{}", krate.name);
            for circle in circles(krate) {
                let _ = writeln!(out, "  circle of {}: {}", circle.len(), circle.join(", "));
            }
            let width = krate.arrows.iter().map(|a| a.from.len() + a.to.len() + 4).max().unwrap_or(0);
            for arrow in &krate.arrows {
                let first = arrow.first();
                let pair = format!("{} -> {}", arrow.from, arrow.to);
                let _ = write!(out, "  {pair:<width$}  {}:{}", first.file, first.line);
                if arrow.occurrences.len() > 1 {
                    let _ = write!(out, " ({} places)", arrow.occurrences.len());
                }
                out.push('\n');
            }
        }
    }
    out
}

fn circles(krate: &CrateModel) -> Vec<Vec<String>> {
    cycles::circles(krate.arrows.iter().map(|a| (a.from.as_str(), a.to.as_str())))
}
