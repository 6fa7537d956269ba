//! Import circles: the strongly connected components of a directed graph (Tarjan).

use std::collections::BTreeMap;

/// The components of more than one node of the graph given by `edges`, each sorted, the list
/// sorted: a circle is reported the same way whatever order the arrows were found in.
pub fn circles<'a>(edges: impl IntoIterator<Item = (&'a str, &'a str)>) -> Vec<Vec<String>> {
    let mut next: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (from, to) in edges {
        next.entry(from).or_default().push(to);
        next.entry(to).or_default();
    }
    let mut tarjan =
        Tarjan { next: &next, index: BTreeMap::new(), low: BTreeMap::new(), stack: Vec::new(), out: Vec::new() };
    for node in next.keys() {
        if !tarjan.index.contains_key(node) {
            tarjan.visit(node);
        }
    }
    let mut out = tarjan.out;
    for circle in &mut out {
        circle.sort();
    }
    out.sort();
    out
}

struct Tarjan<'g, 'a> {
    next: &'g BTreeMap<&'a str, Vec<&'a str>>,
    index: BTreeMap<&'a str, usize>,
    low: BTreeMap<&'a str, usize>,
    stack: Vec<&'a str>,
    out: Vec<Vec<String>>,
}

impl<'a> Tarjan<'_, 'a> {
    // Recursion depth is bounded by the number of top-level modules of one crate (tens).
    fn visit(&mut self, node: &'a str) {
        let index = self.index.len();
        self.index.insert(node, index);
        self.low.insert(node, index);
        self.stack.push(node);
        let next = self.next.get(node).map(Vec::as_slice).unwrap_or_default();
        for &to in next {
            if !self.index.contains_key(to) {
                self.visit(to);
                let low = self.low[node].min(self.low[to]);
                self.low.insert(node, low);
            } else if self.stack.contains(&to) {
                let low = self.low[node].min(self.index[to]);
                self.low.insert(node, low);
            }
        }
        if self.low[node] == index {
            let mut component = Vec::new();
            while let Some(top) = self.stack.pop() {
                component.push(top.to_owned());
                if top == node {
                    break;
                }
            }
            if component.len() > 1 {
                self.out.push(component);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::circles;

    #[test]
    fn a_chain_has_no_circle_and_two_loops_are_two_circles() {
        assert!(circles([("a", "b"), ("b", "c")]).is_empty());
        let found = circles([("c", "a"), ("a", "b"), ("b", "c"), ("d", "e"), ("e", "d"), ("c", "d")]);
        assert_eq!(found, vec![vec!["a", "b", "c"], vec!["d", "e"]]);
    }
}
