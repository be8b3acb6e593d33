//! How large an SVG document grows once it is drawn, checked before usvg draws it.
//!
//! A few kilobytes can ask for millions of paths: a `<use>` repeats what it
//! refers to (and chains of them multiply), and a marker repeats its whole
//! content at every vertex of every path that carries it. usvg builds all of
//! that before we see any of it, and takes seconds to minutes doing so. So we
//! count first, from the raw document: an upper bound of the elements and
//! path segments drawn, refused over `[import] max_elements` / `max_points`.
//!
//! The bound counts every element as drawn (also those in `<defs>`), every
//! `<use>` as a copy of its target, and, where the document has markers, the
//! largest marker at every vertex of every path, line, polyline and polygon.

use std::collections::HashMap;

use usvg::roxmltree::{Document, Node, NodeId};

use crate::config::ImportConfig;
use crate::error::{Error, Result};

/// Elements and path segments a document draws, at most.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DrawnSize {
    pub elements: u64,
    pub segments: u64,
}

impl DrawnSize {
    fn add(self, other: DrawnSize) -> DrawnSize {
        DrawnSize { elements: self.elements.saturating_add(other.elements), segments: self.segments.saturating_add(other.segments) }
    }

    fn times(self, n: u64) -> DrawnSize {
        DrawnSize { elements: self.elements.saturating_mul(n), segments: self.segments.saturating_mul(n) }
    }
}

/// Refuses a document that would draw more than the import limits allow.
pub fn check(doc: &Document, source: &str, limits: &ImportConfig) -> Result<()> {
    let size = drawn_size(doc);
    let refuse = |what: &str, n: u64, setting: &str, limit: u64| {
        Err(Error::Import(format!(
            "{source}: the drawing repeats into up to {n} {what} (through <use> and markers), more than \
             [import] {setting} = {limit}; simplify it or raise the limit"
        )))
    };
    if size.elements > limits.max_elements {
        return refuse("elements", size.elements, "max_elements", limits.max_elements);
    }
    if size.segments > limits.max_points {
        return refuse("path segments", size.segments, "max_points", limits.max_points);
    }
    Ok(())
}

/// The upper bound described in the module comment.
pub fn drawn_size(doc: &Document) -> DrawnSize {
    let elements: Vec<Node> = doc.descendants().filter(|n| n.is_element()).collect();
    let index: HashMap<NodeId, usize> = elements.iter().enumerate().map(|(i, n)| (n.id(), i)).collect();
    let by_id: HashMap<&str, usize> = elements.iter().enumerate().filter_map(|(i, n)| Some((n.attribute("id")?, i))).collect();
    // The element a `<use>` copies, by index.
    let target: Vec<Option<usize>> = elements
        .iter()
        .map(|n| if n.has_tag_name("use") { href(n).and_then(|id| by_id.get(id).copied()) } else { None })
        .collect();
    let parent: Vec<Option<usize>> = elements.iter().map(|n| n.parent().and_then(|p| index.get(&p.id()).copied())).collect();
    let own: Vec<DrawnSize> = elements.iter().map(|n| DrawnSize { elements: 1, segments: segments(n) }).collect();

    // How often each element is drawn: as often as its parent, plus once per
    // drawing of each `<use>` that copies it.
    let mut used_by: Vec<Vec<usize>> = vec![Vec::new(); elements.len()];
    for (u, t) in target.iter().enumerate() {
        if let Some(t) = t {
            used_by[*t].push(u);
        }
    }
    let copies = memoized(elements.len(), |e| parent[e].into_iter().chain(used_by[e].iter().copied()).collect(), |e, deps| {
        let from_parent = if parent[e].is_some() { deps[0] } else { 1 };
        deps.iter().skip(parent[e].is_some() as usize).fold(from_parent, |sum: u64, d| sum.saturating_add(*d))
    });
    let mut total = (0..elements.len()).fold(DrawnSize::default(), |sum, e| sum.add(own[e].times(copies[e])));

    let markers: Vec<usize> = (0..elements.len()).filter(|&e| elements[e].has_tag_name("marker")).collect();
    if !markers.is_empty() {
        // A subtree's size with every `<use>` in it replaced by what it copies.
        let children: Vec<Vec<usize>> = elements.iter().map(|n| n.children().filter_map(|c| index.get(&c.id()).copied()).collect()).collect();
        let subtree = memoized(elements.len(), |e| children[e].iter().copied().chain(target[e]).collect(), |e, deps| {
            deps.iter().fold(own[e], |sum, d| sum.add(*d))
        });
        let largest_marker = markers.iter().fold(DrawnSize::default(), |max, &m| DrawnSize {
            elements: max.elements.max(subtree[m].elements),
            segments: max.segments.max(subtree[m].segments),
        });
        let vertices = (0..elements.len())
            .filter(|&e| ["path", "line", "polyline", "polygon"].iter().any(|t| elements[e].has_tag_name(*t)))
            .fold(0u64, |sum, e| sum.saturating_add(own[e].segments.saturating_add(1).saturating_mul(copies[e])));
        total = total.add(largest_marker.times(vertices));
    }
    total
}

/// The id a `<use>` refers to (`href` or `xlink:href`, `#id` only: usvg
/// loads nothing from other files).
fn href<'a>(node: &Node<'a, '_>) -> Option<&'a str> {
    node.attributes().find(|a| a.name() == "href").and_then(|a| a.value().strip_prefix('#'))
}

/// Segments of an element's own outline, at most (a rounded rectangle is 8).
fn segments(node: &Node) -> u64 {
    match node.tag_name().name() {
        "path" => node.attribute("d").map_or(0, |d| svgtypes::PathParser::from(d).count() as u64),
        "polyline" | "polygon" => node.attribute("points").map_or(0, |p| (svgtypes::NumberListParser::from(p).count() / 2) as u64),
        "rect" => 8,
        "circle" | "ellipse" => 4,
        "line" => 1,
        _ => 0,
    }
}

/// `value(n)` for every node of a graph given by `deps`, computed after the
/// values of its dependencies, without recursion (documents nest deeply). A
/// dependency on a node whose value is still being computed (a cycle, such as
/// a `<use>` inside what it copies, which usvg skips) counts as `T::default()`.
fn memoized<T: Copy + Default>(n: usize, deps: impl Fn(usize) -> Vec<usize>, value: impl Fn(usize, &[T]) -> T) -> Vec<T> {
    #[derive(Clone, Copy, PartialEq)]
    enum State {
        New,
        Open,
        Done,
    }
    let mut state = vec![State::New; n];
    let mut values = vec![T::default(); n];
    for first in 0..n {
        if state[first] != State::New {
            continue;
        }
        let mut stack = vec![(first, false)];
        while let Some((node, expanded)) = stack.pop() {
            if expanded {
                let inputs: Vec<T> = deps(node).iter().map(|&d| if state[d] == State::Done { values[d] } else { T::default() }).collect();
                values[node] = value(node, &inputs);
                state[node] = State::Done;
            } else if state[node] == State::New {
                state[node] = State::Open;
                stack.push((node, true));
                stack.extend(deps(node).into_iter().filter(|&d| state[d] == State::New).map(|d| (d, false)));
            }
        }
    }
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    fn size(body: &str) -> DrawnSize {
        let text = format!(r#"<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink">{body}</svg>"#);
        drawn_size(&Document::parse(&text).unwrap())
    }

    #[test]
    fn plain_elements_count_once() {
        assert_eq!(size(r#"<path d="M0 0 L1 1 L2 0 Z"/><rect width="1" height="1"/>"#), DrawnSize { elements: 3, segments: 4 + 8 });
    }

    #[test]
    fn chains_of_use_multiply() {
        let s = size(
            r##"<defs><path id="p" d="M0 0 L1 1"/>
                <g id="a"><use href="#p"/><use href="#p"/><use href="#p"/></g>
                <g id="b"><use xlink:href="#a"/><use xlink:href="#a"/></g></defs>
                <use href="#b"/><use href="#b"/>"##,
        );
        // The path: once in defs, 3 per drawing of a (1 + 2 per drawing of b (1 + 2)) = 3 * 7 + 1 = 22.
        assert_eq!(s.segments, 2 * 22);
    }

    #[test]
    fn a_use_inside_what_it_copies_counts_once() {
        let s = size(r##"<g id="g"><path d="M0 0 L1 1"/><use href="#g"/></g>"##);
        assert_eq!(s.segments, 2, "the path is drawn once: usvg skips a use that copies itself");
    }

    #[test]
    fn markers_repeat_at_every_vertex() {
        let s = size(
            r#"<marker id="m"><path d="M0 0 L1 1 L2 2"/><circle r="1"/></marker>
                <polyline points="0 0 1 1 2 2 3 3" marker-mid="url(#m)"/>"#,
        );
        // Own: the svg, the marker, its path (3 segments) and circle (4), the polyline (4 points).
        // Repeated: the marker (3 elements, 7 segments) at the 4 vertices of its own
        // path and the 5 of the polyline (a circle carries no markers).
        let own = DrawnSize { elements: 5, segments: 3 + 4 + 4 };
        let vertices = 4 + 5;
        assert_eq!(s, own.add(DrawnSize { elements: 3, segments: 7 }.times(vertices)));
    }

    #[test]
    fn a_marker_bomb_is_refused_naming_the_limit() {
        let inner = "<path d=\"M0 0 C 1 2 3 4 5 5\"/>".repeat(300);
        let points = (0..3000).map(|i| format!("L{} {}", i % 100, i / 100)).collect::<String>();
        let text = format!(
            r#"<svg xmlns="http://www.w3.org/2000/svg"><marker id="m">{inner}</marker><path d="M0 0 {points}" marker-mid="url(#m)"/></svg>"#
        );
        let doc = Document::parse(&text).unwrap();
        let e = check(&doc, "bomb.svg", &ImportConfig::default()).unwrap_err().to_string();
        assert!(e.contains("bomb.svg") && e.contains("max_elements"), "{e}");
    }
}
