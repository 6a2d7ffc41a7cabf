//! Map export: JSON (nodes, edges, the survey report), GraphML (for graph tools: yEd, Gephi,
//! networkx), and a PNG of the graph over the trajectory (plotters). The plot has no text (no
//! font dependency): east right, north up; grey = truth, red = dead reckoning, blue = with
//! loop-closure fixes, black dots = nodes at their estimated positions, green lines = edges.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Result, anyhow};
use plotters::prelude::*;
use serde::Serialize;

use super::map::TopoMap;
use super::survey::{SurveyReport, TrackPoint};

#[derive(Serialize)]
struct JsonMap<'a> {
    report: Option<&'a SurveyReport>,
    match_threshold: f64,
    nodes: &'a [super::map::Node],
    edges: &'a [super::map::Edge],
}

/// The map (and the survey report, if any) as JSON.
pub fn to_json(map: &TopoMap, report: Option<&SurveyReport>) -> Result<String> {
    Ok(serde_json::to_string_pretty(&JsonMap { report, match_threshold: map.match_threshold, nodes: &map.nodes, edges: &map.edges })?)
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// The map as GraphML: node attributes north/east (m), their variances, sample and observation
/// counts; undirected edges.
pub fn to_graphml(map: &TopoMap) -> String {
    let mut s = String::new();
    s.push_str("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    s.push_str("<graphml xmlns=\"http://graphml.graphdrawing.org/xmlns\">\n");
    for (id, ty) in [
        ("north_m", "double"),
        ("east_m", "double"),
        ("var_nn_m2", "double"),
        ("var_ee_m2", "double"),
        ("samples", "int"),
        ("observations", "int"),
    ] {
        let _ = writeln!(s, "  <key id=\"{id}\" for=\"node\" attr.name=\"{id}\" attr.type=\"{ty}\"/>");
    }
    s.push_str("  <graph id=\"topomap\" edgedefault=\"undirected\">\n");
    for n in &map.nodes {
        let _ = writeln!(s, "    <node id=\"{}\">", xml_escape(&format!("n{}", n.id)));
        let _ = writeln!(s, "      <data key=\"north_m\">{}</data>", n.pos_ned_m[0]);
        let _ = writeln!(s, "      <data key=\"east_m\">{}</data>", n.pos_ned_m[1]);
        let _ = writeln!(s, "      <data key=\"var_nn_m2\">{}</data>", n.cov_m2[0]);
        let _ = writeln!(s, "      <data key=\"var_ee_m2\">{}</data>", n.cov_m2[2]);
        let _ = writeln!(s, "      <data key=\"samples\">{}</data>", n.samples.len());
        let _ = writeln!(s, "      <data key=\"observations\">{}</data>", n.observations);
        s.push_str("    </node>\n");
    }
    for (i, e) in map.edges.iter().enumerate() {
        let _ = writeln!(s, "    <edge id=\"e{i}\" source=\"n{}\" target=\"n{}\"/>", e.a, e.b);
    }
    s.push_str("  </graph>\n</graphml>\n");
    s
}

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("plotting: {e:?}")
}

/// PNG of the graph over the trajectory.
pub fn plot(path: &Path, map: &TopoMap, track: &[TrackPoint]) -> Result<()> {
    let pts = track.iter().flat_map(|p| [p.truth_ned_m, p.slam_ned_m, p.dr_ned_m]).chain(map.nodes.iter().map(|n| n.pos_ned_m));
    let (mut n0, mut n1, mut e0, mut e1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for p in pts {
        n0 = n0.min(p[0]);
        n1 = n1.max(p[0]);
        e0 = e0.min(p[1]);
        e1 = e1.max(p[1]);
    }
    if !(n0.is_finite() && e0.is_finite()) {
        return Err(anyhow!("nothing to plot"));
    }
    let pad = 5.0;
    let (n0, n1, e0, e1) = (n0 - pad, n1 + pad, e0 - pad, e1 + pad);
    let root = BitMapBackend::new(path, (800, 800)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root).margin(15).build_cartesian_2d(e0..e1, n0..n1).map_err(err)?;
    chart.configure_mesh().draw().map_err(err)?;
    let line = |f: fn(&TrackPoint) -> [f64; 2]| track.iter().map(move |p| (f(p)[1], f(p)[0])).collect::<Vec<_>>();
    chart.draw_series(LineSeries::new(line(|p| p.truth_ned_m), RGBColor(150, 150, 150).stroke_width(3))).map_err(err)?;
    chart.draw_series(LineSeries::new(line(|p| p.dr_ned_m), RED.stroke_width(1))).map_err(err)?;
    chart.draw_series(LineSeries::new(line(|p| p.slam_ned_m), BLUE.stroke_width(1))).map_err(err)?;
    for e in &map.edges {
        if let (Some(a), Some(b)) = (map.node(e.a), map.node(e.b)) {
            chart
                .draw_series(LineSeries::new(
                    vec![(a.pos_ned_m[1], a.pos_ned_m[0]), (b.pos_ned_m[1], b.pos_ned_m[0])],
                    GREEN.stroke_width(2),
                ))
                .map_err(err)?;
        }
    }
    chart.draw_series(map.nodes.iter().map(|n| Circle::new((n.pos_ned_m[1], n.pos_ned_m[0]), 4, BLACK.filled()))).map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}
