//! `xformOp`s: each prim's local transform from its `xformOpOrder`, as
//! column-vector matrices composed root to leaf.

use super::parse::Prim;
use crate::bytes::{corrupt, unsupported};
use crate::ErrorKind;

/// Column-vector affine transform (`p' = M p`).
pub(crate) type Mat4 = [[f64; 4]; 4];

/// The transform of a prim with no ops.
pub(crate) const IDENTITY: Mat4 =
    [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];

/// `a b`: apply `b`, then `a`.
pub(super) fn mul(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut c = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            c[i][j] = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn translate(t: [f64; 3]) -> Mat4 {
    let mut m = IDENTITY;
    for a in 0..3 {
        m[a][3] = t[a];
    }
    m
}

fn scale(s: [f64; 3]) -> Mat4 {
    let mut m = IDENTITY;
    for a in 0..3 {
        m[a][a] = s[a];
    }
    m
}

/// Right-handed rotation by `deg` degrees about axis 0, 1 or 2.
fn rotate(axis: usize, deg: f64) -> Mat4 {
    let (s, c) = deg.to_radians().sin_cos();
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut m = IDENTITY;
    m[u][u] = c;
    m[u][v] = -s;
    m[v][u] = s;
    m[v][v] = c;
    m
}

/// `m p`, in `f64` then back to `f32`.
pub(super) fn transform_point(m: &Mat4, p: [f32; 3]) -> [f32; 3] {
    let p = [p[0] as f64, p[1] as f64, p[2] as f64];
    let mut out = [0f32; 3];
    for (a, o) in out.iter_mut().enumerate() {
        *o = (m[a][0] * p[0] + m[a][1] * p[1] + m[a][2] * p[2] + m[a][3]) as f32;
    }
    out
}

/// The prim's local transform from its `xformOpOrder`, and whether it
/// resets the inherited stack.
pub(super) fn local_xform(prim: &Prim) -> Result<(Mat4, bool), ErrorKind> {
    let Some(order) = prim.value("xformOpOrder") else {
        return Ok((IDENTITY, false));
    };
    let ops = order.as_list().ok_or_else(|| corrupt(format!("prim '{}': xformOpOrder is not a list", prim.name)))?;
    let mut m = IDENTITY;
    let mut reset = false;
    for op in ops {
        let op =
            op.as_str().ok_or_else(|| corrupt(format!("prim '{}': xformOpOrder entry is not a token", prim.name)))?;
        if op == "!resetXformStack!" {
            reset = true;
            m = IDENTITY;
            continue;
        }
        let (inverse, attr) = match op.strip_prefix("!invert!") {
            Some(a) => (true, a),
            None => (false, op),
        };
        let bad = |why: &str| corrupt(format!("prim '{}': {op}: {why}", prim.name));
        let kind = attr.strip_prefix("xformOp:").ok_or_else(|| bad("not an xformOp"))?.split(':').next().unwrap_or("");
        let v = prim.value(attr).ok_or_else(|| bad("op listed but has no value"))?;
        let vec3 = || v.as_vec3().ok_or_else(|| bad("expected 3 numbers"));
        let num = || v.as_f64().ok_or_else(|| bad("expected a number"));
        if inverse && kind != "translate" {
            return Err(unsupported(format!(
                "prim '{}': inverted op {op} (only inverted translates are read)",
                prim.name
            )));
        }
        let op_m = match kind {
            "translate" => {
                let t = vec3()?;
                translate(if inverse { t.map(|x| -x) } else { t })
            }
            "scale" => scale(vec3()?),
            "rotateX" => rotate(0, num()?),
            "rotateY" => rotate(1, num()?),
            "rotateZ" => rotate(2, num()?),
            r if r.len() == 9 && r.starts_with("rotate") => {
                // rotateXYZ applies X first: M = R_Z R_Y R_X.
                let angles = vec3()?;
                let mut rm = IDENTITY;
                for (k, ch) in r[6..].chars().enumerate() {
                    let axis = match ch {
                        'X' => 0,
                        'Y' => 1,
                        'Z' => 2,
                        _ => return Err(bad("unknown rotation order")),
                    };
                    rm = mul(&rotate(axis, angles[k]), &rm);
                }
                rm
            }
            "orient" => {
                let q = match v.as_list() {
                    Some([w, x, y, z]) => [w, x, y, z].map(|c| c.as_f64().unwrap_or(f64::NAN)),
                    _ => return Err(bad("expected a quaternion (w, x, y, z)")),
                };
                let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
                let [w, x, y, z] = q.map(|c| c / n);
                [
                    [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y), 0.0],
                    [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x), 0.0],
                    [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y), 0.0],
                    [0.0, 0.0, 0.0, 1.0],
                ]
            }
            "transform" => {
                // USD matrices are row-vector (`p' = p M`, translation in the
                // last row): transpose into our column-vector convention.
                let rows = v.as_list().filter(|r| r.len() == 4).ok_or_else(|| bad("expected a 4x4 matrix"))?;
                let mut m4 = IDENTITY;
                for (i, row) in rows.iter().enumerate() {
                    let row = row.as_list().filter(|r| r.len() == 4).ok_or_else(|| bad("expected a 4x4 matrix"))?;
                    for (j, x) in row.iter().enumerate() {
                        m4[j][i] = x.as_f64().ok_or_else(|| bad("expected numbers"))?;
                    }
                }
                m4
            }
            other => return Err(unsupported(format!("prim '{}': xformOp kind '{other}'", prim.name))),
        };
        m = mul(&m, &op_m);
    }
    Ok((m, reset))
}
