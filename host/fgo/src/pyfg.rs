//! Reader for the PyFactorGraph text format (`.pyfg`, MarineRoboticsGroup's py-factor-graph; the
//! GOATS data sets in GTSAM's `Data` folder): 2-D poses, landmarks (acoustic beacons), SE2
//! odometry and range measurements.
//!
//! Lines (whitespace separated; blank lines and `#` comments skipped):
//! - `VERTEX_SE2 t_s SYM x y theta`: a pose and its (optional) initial guess;
//! - `VERTEX_XY SYM x y`: a landmark (beacon) and its surveyed / guessed position;
//! - `EDGE_SE2 t_s SYM_I SYM_J dx dy dtheta c11 c12 c13 c22 c23 c33`: relative pose `i^-1 j`, with
//!   the upper triangle of its covariance (x, y, theta order);
//! - `EDGE_RANGE t_s SYM_POSE SYM_BEACON range_m variance_m2`.
//!
//! Everything else is an error naming the file and the line, as are a non-finite number, a
//! covariance that is not symmetric positive definite (a negative variance), an edge to a vertex
//! that was never declared, a duplicate vertex, and a pose that the odometry does not connect to
//! the first pose (dead reckoning could not place it).

use std::path::Path;

use nalgebra::Matrix3;

use super::FgoError;

/// 2-D pose: position (m) and heading (rad) of the body in the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose2 {
    pub x_m: f64,
    pub y_m: f64,
    pub theta_rad: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct PoseVertex {
    pub name: String,
    pub t_s: f64,
    /// The file's value: used only as an optional initial guess.
    pub guess: Pose2,
    pub line: usize,
}

#[derive(Debug, Clone, PartialEq)]
pub struct BeaconVertex {
    pub name: String,
    pub pos_m: [f64; 2],
    pub line: usize,
}

/// Relative pose `i^-1 j` with its covariance.
#[derive(Debug, Clone, PartialEq)]
pub struct Se2Edge {
    pub i: usize,
    pub j: usize,
    pub measured: Pose2,
    pub cov: Matrix3<f64>,
    pub line: usize,
}

/// Range from pose `pose` to beacon `beacon`.
#[derive(Debug, Clone, PartialEq)]
pub struct RangeEdge {
    pub pose: usize,
    pub beacon: usize,
    pub range_m: f64,
    pub var_m2: f64,
    pub line: usize,
}

/// A parsed file: vertex indices in declaration order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PyFg {
    pub poses: Vec<PoseVertex>,
    pub beacons: Vec<BeaconVertex>,
    pub odometry: Vec<Se2Edge>,
    pub ranges: Vec<RangeEdge>,
}

enum Vertex {
    Pose(usize),
    Beacon(usize),
}

impl PyFg {
    /// Read and check a file.
    pub fn read(path: &Path) -> Result<Self, FgoError> {
        let text = std::fs::read_to_string(path).map_err(|e| FgoError::Input(format!("cannot read {}: {e}", path.display())))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parse and check `text`; `name` (the file) is used in the errors.
    pub fn parse(text: &str, name: &str) -> Result<Self, FgoError> {
        let mut g = PyFg::default();
        let mut index: std::collections::HashMap<String, Vertex> = std::collections::HashMap::new();
        for (k, raw) in text.lines().enumerate() {
            let line = k + 1;
            let err = |msg: String| FgoError::Input(format!("{name}:{line}: {msg}"));
            let content = raw.trim();
            if content.is_empty() || content.starts_with('#') {
                continue;
            }
            let f: Vec<&str> = content.split_whitespace().collect();
            let kind = f[0];
            let want = match kind {
                "VERTEX_SE2" => 6,
                "VERTEX_XY" => 4,
                "EDGE_SE2" => 13,
                "EDGE_RANGE" => 6,
                other => {
                    return Err(err(format!("unknown line type {other:?} (supported: VERTEX_SE2, VERTEX_XY, EDGE_SE2, EDGE_RANGE)")));
                }
            };
            if f.len() != want {
                return Err(err(format!("{kind} needs {want} fields, found {}", f.len())));
            }
            let num = |i: usize, what: &str| -> Result<f64, FgoError> {
                let v: f64 = f[i].parse().map_err(|_| err(format!("{what} {:?} is not a number", f[i])))?;
                if !v.is_finite() {
                    return Err(err(format!("{what} is {v} (not finite)")));
                }
                Ok(v)
            };
            let declare = |index: &mut std::collections::HashMap<String, Vertex>, sym: &str, v: Vertex| {
                if index.contains_key(sym) {
                    return Err(err(format!("vertex {sym} declared twice")));
                }
                index.insert(sym.to_string(), v);
                Ok(())
            };
            let pose_of = |index: &std::collections::HashMap<String, Vertex>, sym: &str| match index.get(sym) {
                Some(Vertex::Pose(i)) => Ok(*i),
                Some(Vertex::Beacon(_)) => Err(err(format!("{sym} is a VERTEX_XY, a pose (VERTEX_SE2) is needed here"))),
                None => Err(err(format!("pose {sym} was not declared (no VERTEX_SE2 line before this one)"))),
            };
            match kind {
                "VERTEX_SE2" => {
                    let (t_s, x, y, th) = (num(1, "time")?, num(3, "x")?, num(4, "y")?, num(5, "theta")?);
                    declare(&mut index, f[2], Vertex::Pose(g.poses.len()))?;
                    g.poses.push(PoseVertex { name: f[2].to_string(), t_s, guess: Pose2 { x_m: x, y_m: y, theta_rad: th }, line });
                }
                "VERTEX_XY" => {
                    let (x, y) = (num(2, "x")?, num(3, "y")?);
                    declare(&mut index, f[1], Vertex::Beacon(g.beacons.len()))?;
                    g.beacons.push(BeaconVertex { name: f[1].to_string(), pos_m: [x, y], line });
                }
                "EDGE_SE2" => {
                    num(1, "time")?;
                    let (i, j) = (pose_of(&index, f[2])?, pose_of(&index, f[3])?);
                    if i == j {
                        return Err(err(format!("EDGE_SE2 from {} to itself", f[2])));
                    }
                    let m = Pose2 { x_m: num(4, "dx")?, y_m: num(5, "dy")?, theta_rad: num(6, "dtheta")? };
                    let c = [num(7, "c11")?, num(8, "c12")?, num(9, "c13")?, num(10, "c22")?, num(11, "c23")?, num(12, "c33")?];
                    let cov = Matrix3::new(c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5]);
                    for (d, what) in [(c[0], "c11"), (c[3], "c22"), (c[5], "c33")] {
                        if !(d > 0.0) {
                            return Err(err(format!("variance {what} = {d} must be > 0")));
                        }
                    }
                    if cov.cholesky().is_none() {
                        return Err(err("covariance is not positive definite".into()));
                    }
                    g.odometry.push(Se2Edge { i, j, measured: m, cov, line });
                }
                "EDGE_RANGE" => {
                    num(1, "time")?;
                    let pose = pose_of(&index, f[2])?;
                    let beacon = match index.get(f[3]) {
                        Some(Vertex::Beacon(b)) => *b,
                        Some(Vertex::Pose(_)) => {
                            return Err(err(format!("range between two poses ({} {}) is not supported", f[2], f[3])));
                        }
                        None => return Err(err(format!("range to undeclared beacon {} (no VERTEX_XY line before this one)", f[3]))),
                    };
                    let (range_m, var_m2) = (num(4, "range")?, num(5, "variance")?);
                    if range_m < 0.0 {
                        return Err(err(format!("negative range {range_m}")));
                    }
                    if !(var_m2 > 0.0) {
                        return Err(err(format!("range variance {var_m2} must be > 0")));
                    }
                    g.ranges.push(RangeEdge { pose, beacon, range_m, var_m2, line });
                }
                _ => unreachable!("kind checked above"),
            }
        }
        if g.poses.is_empty() {
            return Err(FgoError::Input(format!("{name}: no VERTEX_SE2 line (no pose)")));
        }
        // every pose reachable from the first one through the odometry
        let n = g.poses.len();
        let mut adj: Vec<Vec<usize>> = vec![Vec::new(); n];
        for e in &g.odometry {
            adj[e.i].push(e.j);
            adj[e.j].push(e.i);
        }
        let mut seen = vec![false; n];
        let mut stack = vec![0];
        seen[0] = true;
        while let Some(a) = stack.pop() {
            for &b in &adj[a] {
                if !seen[b] {
                    seen[b] = true;
                    stack.push(b);
                }
            }
        }
        if let Some(k) = seen.iter().position(|s| !s) {
            let p = &g.poses[k];
            return Err(FgoError::Input(format!(
                "{name}:{}: pose {} is not connected to the first pose {} by EDGE_SE2 odometry",
                p.line, p.name, g.poses[0].name
            )));
        }
        Ok(g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const OK: &str = "VERTEX_XY L0 10.0 5.0\nVERTEX_SE2 0.0 A0 0 0 0\nVERTEX_SE2 1.0 A1 1 0 0\n\
EDGE_SE2 1.0 A0 A1 1.0 0.0 0.0 0.0004 0 0 0.0004 0 0.000004\nEDGE_RANGE 1.0 A1 L0 10.3 0.5625\n";

    fn bad(text: &str) -> String {
        match PyFg::parse(text, "f.pyfg") {
            Err(FgoError::Input(s)) => s,
            other => panic!("expected an input error, got {other:?}"),
        }
    }

    #[test]
    fn reads_a_good_file() {
        let g = PyFg::parse(OK, "f.pyfg").unwrap();
        assert_eq!((g.poses.len(), g.beacons.len(), g.odometry.len(), g.ranges.len()), (2, 1, 1, 1));
        assert_eq!(g.odometry[0].cov[(2, 2)], 0.000004);
        assert_eq!((g.ranges[0].pose, g.ranges[0].beacon, g.ranges[0].line), (1, 0, 5));
    }

    #[test]
    fn bad_lines_are_named() {
        assert!(bad(&format!("{OK}VERTEX_SE3 0 A2 0 0 0\n")).starts_with("f.pyfg:6: unknown line type"));
        assert!(bad(&OK.replace("10.3", "NaN")).starts_with("f.pyfg:5: range"));
        assert!(bad(&OK.replace("0.0004 0 0 0.0004", "-0.0004 0 0 0.0004")).starts_with("f.pyfg:4: variance c11"));
        assert!(bad(&OK.replace("0.5625", "-0.5625")).starts_with("f.pyfg:5: range variance"));
        assert!(bad(&OK.replace("A1 L0", "A1 L7")).starts_with("f.pyfg:5: range to undeclared beacon L7"));
        assert!(bad(&format!("{OK}VERTEX_SE2 2.0 A2 5 5 0\n")).starts_with("f.pyfg:6: pose A2 is not connected"));
        assert!(bad(&OK.replace("A0 A1 1.0", "A0 A9 1.0")).starts_with("f.pyfg:4: pose A9 was not declared"));
        assert!(bad(&OK.replace("EDGE_RANGE 1.0 A1 L0 10.3", "EDGE_RANGE 1.0 A1 L0")).starts_with("f.pyfg:5: EDGE_RANGE needs 6"));
        assert!(bad(&format!("{OK}VERTEX_XY L0 1 1\n")).starts_with("f.pyfg:6: vertex L0 declared twice"));
        assert!(bad(&OK.replace("0.0004 0 0 0.0004", "0.0004 0.1 0 0.0004")).contains("f.pyfg:4: covariance is not positive definite"));
    }
}
