//! The CSV files of calibration: the pose list a plan writes, and the measurements.
//!
//! A header line names the columns (any order; `#` starts a comment line):
//! - `cmd_X` … `cmd_C`: the commanded pose, mm and degrees;
//! - `q1` … `qN`: the commanded joints, mm or degrees (when absent, the nominal
//!   inverse kinematics of the commanded pose gives them);
//! - `X Y Z` and the machine's measured angles (H-4: `A C`; hexapod: `A B C`;
//!   hexapod-xy: `A B`): the tool pose measured, mm and degrees, in the frame the
//!   machine's poses are programmed in.
//!
//! Every error names the file, the line and the column.

use super::fit::Sample;
use super::model::Model;

const AXIS: [&str; 6] = ["X", "Y", "Z", "A", "B", "C"];

/// A parsed CSV: header and rows of (line, fields with their 1-based columns).
pub struct Table {
    origin: String,
    header: Vec<String>,
    header_line: usize,
    rows: Vec<(usize, Vec<(usize, String)>)>,
}

fn fields(line: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut col = 1;
    for f in line.split(',') {
        let lead = f.len() - f.trim_start().len();
        out.push((col + lead, f.trim().to_string()));
        col += f.chars().count() + 1;
    }
    out
}

impl Table {
    /// Parses `text`; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Table, String> {
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l))
            .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
        let (header_line, h) = lines.next().ok_or(format!("{origin}: no header line"))?;
        let header: Vec<String> = fields(h).into_iter().map(|f| f.1).collect();
        for (i, name) in header.iter().enumerate() {
            if header[..i].contains(name) {
                let col = fields(h)[i].0;
                return Err(format!(
                    "{origin}:{header_line}:{col}: column `{name}` given twice"
                ));
            }
        }
        let mut rows = Vec::new();
        for (n, l) in lines {
            let f = fields(l);
            if f.len() != header.len() {
                let col = f.get(header.len()).map_or(l.chars().count() + 1, |x| x.0);
                return Err(format!(
                    "{origin}:{n}:{col}: {} fields, the header has {}",
                    f.len(),
                    header.len()
                ));
            }
            rows.push((n, f));
        }
        Ok(Table {
            origin: origin.into(),
            header,
            header_line,
            rows,
        })
    }

    /// Index of column `name`.
    pub fn column(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// Like [`Table::column`], but missing is an error.
    pub fn require(&self, name: &str) -> Result<usize, String> {
        self.column(name).ok_or(format!(
            "{}:{}:1: no column `{name}` (columns: {})",
            self.origin,
            self.header_line,
            self.header.join(",")
        ))
    }

    /// The number in row `r`, column `c`.
    pub fn number(&self, r: usize, c: usize) -> Result<f64, String> {
        let (line, f) = &self.rows[r];
        let (col, text) = &f[c];
        text.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or(format!(
                "{}:{line}:{col}: `{text}` in column `{}` is not a number",
                self.origin, self.header[c]
            ))
    }

    /// Rows.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// No rows?
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// `file:line:column` of row `r`'s field in column `c`.
    pub fn place(&self, r: usize, c: usize) -> String {
        let Some((line, f)) = self.rows.get(r) else {
            return format!("{}:{}:1", self.origin, self.header_line);
        };
        let col = f.get(c).map_or(1, |x| x.0);
        format!("{}:{line}:{col}", self.origin)
    }

    /// The file's name as errors give it.
    pub fn origin(&self) -> &str {
        &self.origin
    }

    /// `file:line` of row `r`.
    pub fn at(&self, r: usize) -> String {
        format!("{}:{}", self.origin, self.rows[r].0)
    }
}

/// The commanded poses of a table with `cmd_*` columns (an axis without its column is
/// 0), or `None` if it has none.
pub fn poses(t: &Table) -> Result<Option<Vec<[f64; 6]>>, String> {
    let cols: Vec<Option<usize>> = AXIS.iter().map(|a| t.column(&format!("cmd_{a}"))).collect();
    if cols.iter().all(Option::is_none) {
        return Ok(None);
    }
    let mut out = Vec::new();
    for r in 0..t.len() {
        let mut p = [0.0; 6];
        for k in 0..6 {
            if let Some(c) = cols[k] {
                p[k] = t.number(r, c)?;
            }
        }
        out.push(p);
    }
    Ok(Some(out))
}

/// A row's joints and the internal pose forward kinematics starts from.
pub type Joints = (Vec<f64>, Vec<f64>);

/// Each row's joints and the internal pose to start forward kinematics from: the
/// `q` columns if there are, else the nominal inverse of the commanded pose.
pub fn joints(t: &Table, model: &Model) -> Result<Vec<Joints>, String> {
    let th = model.nominal();
    let home = model.inverse(&th, &model.home).map(|h| h.1);
    let home = home.ok_or("the machine's home pose is out of reach of its own model")?;
    let poses = poses(t)?;
    let has_q = t.column("q1").is_some();
    let mut out = Vec::new();
    for r in 0..t.len() {
        let nominal = poses.as_ref().map(|p| model.inverse(&th, &p[r]));
        if has_q {
            let mut q = Vec::new();
            for j in 0..model.joints() {
                q.push(t.number(r, t.require(&format!("q{}", j + 1))?)?);
            }
            let guess = nominal.flatten().map_or(home.clone(), |n| n.1);
            out.push((q, guess));
        } else {
            match nominal {
                None => {
                    return Err(format!(
                        "{}:1: neither joints (q1…) nor commanded poses (cmd_X…)",
                        t.origin
                    ))
                }
                Some(None) => {
                    return Err(format!("{}: the commanded pose is out of reach", t.at(r)))
                }
                Some(Some(n)) => out.push(n),
            }
        }
    }
    Ok(out)
}

/// The measurements of a table: joints and measured tool poses.
pub fn measurements(t: &Table, model: &Model) -> Result<Vec<Sample>, String> {
    let cols = model
        .measured_axes()
        .iter()
        .map(|&a| t.require(AXIS[a]))
        .collect::<Result<Vec<_>, _>>()?;
    let js = joints(t, model)?;
    let mut out = Vec::new();
    for (r, (q, guess)) in js.into_iter().enumerate() {
        let measured = cols
            .iter()
            .map(|&c| t.number(r, c))
            .collect::<Result<_, _>>()?;
        out.push(Sample { q, measured, guess });
    }
    if out.is_empty() {
        return Err(format!("{}: no measurements", t.origin));
    }
    Ok(out)
}

fn num(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

/// A pose list: commanded pose and joints per row, and with `measured` the measured
/// tool pose too.
pub fn write(
    model: &Model,
    poses: &[[f64; 6]],
    joints: &[Vec<f64>],
    measured: Option<&[Vec<f64>]>,
) -> String {
    let mut head: Vec<String> = AXIS.iter().map(|a| format!("cmd_{a}")).collect();
    head.extend((1..=model.joints()).map(|j| format!("q{j}")));
    if measured.is_some() {
        head.extend(model.measured_axes().iter().map(|&a| AXIS[a].to_string()));
    }
    let mut out = head.join(",") + "\n";
    for (r, p) in poses.iter().enumerate() {
        let mut row: Vec<String> = p.iter().map(|v| num(*v)).collect();
        row.extend(joints[r].iter().map(|v| num(*v)));
        if let Some(m) = measured {
            row.extend(m[r].iter().map(|v| num(*v)));
        }
        out += &(row.join(",") + "\n");
    }
    out
}

/// A number as the machine file writes it: to the nanometre, trailing zeros dropped.
pub fn format_number(v: f64) -> String {
    num(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_name_file_line_and_column() {
        let e = Table::parse("# c\nX,Y\n1,2\n3\n", "m.csv").err().unwrap();
        assert_eq!(e, "m.csv:4:2: 1 fields, the header has 2");
        let t = Table::parse("X, Y\n1, 2x\n", "m.csv").unwrap();
        assert_eq!(
            t.number(0, 1).unwrap_err(),
            "m.csv:2:4: `2x` in column `Y` is not a number"
        );
        assert!(t
            .require("Z")
            .unwrap_err()
            .starts_with("m.csv:1:1: no column `Z`"));
        let e = Table::parse("X,X\n", "m.csv").err().unwrap();
        assert_eq!(e, "m.csv:1:3: column `X` given twice");
    }
}
