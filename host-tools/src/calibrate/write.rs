//! The corrected machine file: the original text with only the identified parameters'
//! fields rewritten, each under a comment that gives its old line. Everything else is
//! left byte for byte.
//!
//! A joint's zero offset is written into its homing switch position (`homing =
//! { switch_at = … }`): the joint reads `switch_at` where its switch trips, so a joint
//! that is really at `q + offset` there homes right with `switch_at + offset`. A joint
//! without a homing table cannot take its offset; the notes say so.

use super::data::format_number;
use super::fit::Fit;
use super::model::{Kind, Model};

/// A field of the machine file: section, key, first parameter, values per row, rows
/// (1 row: a scalar when `per_row` is 1, else a flat array).
struct Field {
    section: &'static str,
    key: &'static str,
    first: usize,
    per_row: usize,
    rows: usize,
    /// A radius-and-angles pair the explicit field replaces (the hexapod's circles).
    circle: Option<[&'static str; 2]>,
}

const fn field(
    section: &'static str,
    key: &'static str,
    first: usize,
    per_row: usize,
    rows: usize,
) -> Field {
    Field {
        section,
        key,
        first,
        per_row,
        rows,
        circle: None,
    }
}

fn fields(kind: &Kind) -> Vec<Field> {
    let joints = |at: usize, circle: bool| {
        let mut b = field("hexapod", "base", at, 3, 6);
        let mut p = field("hexapod", "platform", at + 18, 3, 6);
        if circle {
            b.circle = Some(["base_radius", "base_angles"]);
            p.circle = Some(["platform_radius", "platform_angles"]);
        }
        [b, p]
    };
    match kind {
        Kind::H4 { .. } => vec![
            field("h4_table", "table_pivot", 0, 3, 1),
            field("h4_table", "tool_length", 3, 1, 1),
            field("h4_table", "attach", 4, 3, 4),
            field("h4_table", "rails", 16, 2, 4),
            field("h4_table", "forearm", 24, 1, 1),
            field("h4_table", "bar_half", 25, 1, 1),
        ],
        Kind::Hexapod => joints(0, true).into(),
        Kind::HexapodXy { .. } => {
            let mut f = vec![
                field("hexapod_xy", "platform_home", 0, 3, 1),
                field("hexapod_xy", "tool_z", 3, 1, 1),
            ];
            f.extend(joints(6, true));
            f
        }
    }
}

fn value(th: &[f64], f: &Field) -> String {
    let n = |i: usize| format_number(th[f.first + i]);
    if f.rows == 1 && f.per_row == 1 {
        return n(0);
    }
    let row = |r: usize| {
        (0..f.per_row)
            .map(|k| n(r * f.per_row + k))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if f.rows == 1 {
        format!("[{}]", row(0))
    } else {
        format!(
            "[{}]",
            (0..f.rows)
                .map(|r| format!("[{}]", row(r)))
                .collect::<Vec<_>>()
                .join(", ")
        )
    }
}

/// Line range of section `name` (`[name]`), or of the `index`-th `[[joints]]`.
fn section(lines: &[String], header: &str, index: usize) -> Option<(usize, usize)> {
    let starts: Vec<usize> = (0..lines.len())
        .filter(|&i| lines[i].trim() == header)
        .collect();
    let s = *starts.get(index)?;
    let e = (s + 1..lines.len())
        .find(|&i| lines[i].trim_start().starts_with('['))
        .unwrap_or(lines.len());
    Some((s, e))
}

fn key_line(lines: &[String], (s, e): (usize, usize), key: &str) -> Option<usize> {
    (s + 1..e).find(|&i| {
        let t = lines[i].trim_start();
        t.strip_prefix(key)
            .is_some_and(|rest| rest.trim_start().starts_with('='))
    })
}

/// The H-4's home pose holds the table angle, a joint itself: when the rolling
/// table's zero moves into its travel past the home angle, the home angle follows to
/// the new end of the travel.
fn home_in_travel(lines: &mut Vec<String>, model: &Model, fit: &Fit) {
    let Kind::H4 { .. } = model.kind else { return };
    let (i, travel) = (30, model.limits[4]);
    if !fit.ident.free.contains(&i) {
        return;
    }
    let a = model.home[3].clamp(travel[0] + fit.theta[i], travel[1] + fit.theta[i]);
    if a == model.home[3] {
        return;
    }
    let end = lines
        .iter()
        .position(|l| l.trim_start().starts_with('['))
        .unwrap_or(lines.len());
    let is_home = |l: &String| {
        l.strip_prefix("home")
            .is_some_and(|r| r.trim_start().starts_with('='))
    };
    let Some(h) = lines[..end].iter().position(is_home) else {
        return;
    };
    let mut home = model.home;
    home[3] = a;
    let old = lines[h].trim().to_string();
    let values: Vec<String> = home.iter().map(|v| format_number(*v)).collect();
    lines[h] = format!(
        "home = [{}]   # A moved into the table's corrected travel",
        values.join(", ")
    );
    lines.insert(h, format!("# was: {old}"));
}

/// The number after the first `=` at or after byte `from` of `line`: its byte range
/// and value.
fn number_after(line: &str, from: usize) -> Option<(usize, usize, f64)> {
    let eq = from + line[from..].find('=')? + 1;
    let start = eq + line[eq..].len() - line[eq..].trim_start().len();
    let end = start
        + line[start..]
            .find([',', '}', ' ', '#'])
            .unwrap_or(line.len() - start);
    Some((start, end, line[start..end].parse().ok()?))
}

/// The corrected text of the machine file `text` for `fit`, and notes on what could
/// not be written.
pub fn corrected(text: &str, model: &Model, fit: &Fit) -> Result<(String, Vec<String>), String> {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let mut notes = Vec::new();
    let free = |i: usize| fit.ident.free.contains(&i);
    let fields = fields(&model.kind);
    for f in &fields {
        if !(f.first..f.first + f.per_row * f.rows).any(free) {
            continue;
        }
        let sec = section(&lines, &format!("[{}]", f.section), 0)
            .ok_or(format!("no [{}] section", f.section))?;
        let new = format!(
            "{} = {}   # calibrated (nc-send calibrate)",
            f.key,
            value(&fit.theta, f)
        );
        if let Some(i) = key_line(&lines, sec, f.key) {
            let old = lines[i].trim().to_string();
            lines[i] = new;
            lines.insert(i, format!("# was: {old}"));
        } else if let Some([r, a]) = f.circle {
            let (ri, ai) = (key_line(&lines, sec, r), key_line(&lines, sec, a));
            let (Some(ri), Some(ai)) = (ri, ai) else {
                return Err(format!("[{}] has neither {} nor {r}/{a}", f.section, f.key));
            };
            for i in [ri, ai] {
                lines[i] = format!("# was: {}", lines[i].trim());
            }
            lines.insert(ri.max(ai) + 1, new);
        } else {
            return Err(format!("[{}] has no {}", f.section, f.key));
        }
    }
    for i in 0..model.params.len() {
        let name = &model.params[i].name;
        let joint = name
            .strip_prefix("offset[q")
            .and_then(|r| r.strip_suffix(']'));
        let Some(joint) = joint.and_then(|j| j.parse::<usize>().ok()) else {
            continue;
        };
        let joint = joint - 1;
        if !free(i) {
            continue;
        }
        let Some(sec) = section(&lines, "[[joints]]", joint) else {
            return Err(format!("no [[joints]] entry {}", joint + 1));
        };
        let edited = key_line(&lines, sec, "homing").and_then(|h| {
            let line = lines[h].clone();
            let (start, end, old) = number_after(&line, line.find("switch_at")?)?;
            let new = format_number(old + fit.theta[i]);
            lines[h] = format!("{}{new}{}", &line[..start], &line[end..]);
            lines.insert(
                h,
                format!(
                    "# was: {}   ({name} moved into the joint's zero)",
                    line.trim()
                ),
            );
            Some(())
        });
        if edited.is_some() {
            // The whole joint coordinate moves by the offset: its travel too, so the
            // same physical travel stays allowed.
            for key in ["max", "min"] {
                let sec = section(&lines, "[[joints]]", joint).ok_or("joint lost")?;
                let Some(k) = key_line(&lines, sec, key) else {
                    continue;
                };
                let line = lines[k].clone();
                let Some((start, end, old)) = number_after(&line, 0) else {
                    continue;
                };
                let new = format_number(old + fit.theta[i]);
                lines[k] = format!("{}{new}{}", &line[..start], &line[end..]);
                lines.insert(k, format!("# was: {}   ({name})", line.trim()));
            }
        }
        if edited.is_none() {
            notes.push(format!(
                "{name} = {} ± {}: not written (the joint has no homing switch_at to carry it)",
                format_number(fit.theta[i]),
                format_number(fit.sigma[i])
            ));
        }
    }
    home_in_travel(&mut lines, model, fit);
    let mut out = lines.join("\n");
    if text.ends_with('\n') {
        out.push('\n');
    }
    Ok((out, notes))
}
