//! `nc-send tune --write`: the machine file with one joint's `servo = { … }` gains
//! rewritten in place (kp, ki, kd, kvff, kaff), under a comment that gives the old
//! line, and for a joint that runs LQG its `lqg`, `lqg_gains` and `lqg_model` lines
//! ([`set_line`]) the same way; every other byte of the file is kept.

/// The rewritten file and the joint's new `servo` line.
#[derive(Clone, Debug, PartialEq)]
pub struct Rewritten {
    /// The whole file.
    pub text: String,
    /// The new `servo = { … }` line.
    pub line: String,
}

/// A gain as written: five significant digits.
fn number(v: f64) -> String {
    if v == 0.0 {
        "0.0".into()
    } else {
        format!("{v:.4e}")
    }
}

/// `text` with the `servo` line of the `joint`-th `[[joints]]` table given `fields`
/// (each replaced where it is, or added after the opening brace).
pub fn rewrite(text: &str, joint: usize, fields: &[(&str, f64)]) -> Result<Rewritten, String> {
    let (offset, line) = key_line(text, joint, "servo")
        .ok_or_else(|| format!("joints[{joint}]: no `servo = {{ … }}` line to rewrite"))?;
    let body = line.trim_end_matches(['\n', '\r']);
    let (open, close) = match (body.find('{'), body.rfind('}')) {
        (Some(o), Some(c)) if o < c => (o, c),
        _ => {
            return Err(format!(
                "joints[{joint}].servo: not a one-line inline table `servo = {{ … }}`"
            ))
        }
    };
    let mut items: Vec<String> = body[open + 1..close]
        .split(',')
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .collect();
    for (key, v) in fields {
        let item = format!("{key} = {}", number(*v));
        let place = items
            .iter()
            .position(|s| s.split('=').next().map(str::trim) == Some(key));
        match place {
            Some(i) => items[i] = item,
            None => {
                // After `law` (and the gains already placed), before the rest.
                let after = items
                    .iter()
                    .rposition(|s| {
                        let k = s.split('=').next().unwrap_or("").trim();
                        k == "law" || fields.iter().any(|(f, _)| *f == k)
                    })
                    .map_or(0, |i| i + 1);
                items.insert(after, item);
            }
        }
    }
    let indent = &body[..body.len() - body.trim_start().len()];
    let new_line = format!(
        "{}{{ {} }}{}",
        &body[..open],
        items.join(", "),
        &body[close + 1..]
    );
    let ending = &line[body.len()..];
    let ending = if ending.is_empty() { "\n" } else { ending };
    let mut out = String::with_capacity(text.len() + 2 * line.len());
    out.push_str(&text[..offset]);
    out.push_str(&format!(
        "{indent}# nc-send tune: was {}{ending}",
        body.trim_start()
    ));
    out.push_str(&new_line);
    out.push_str(&line[body.len()..]);
    out.push_str(&text[offset + line.len()..]);
    Ok(Rewritten {
        text: out,
        line: new_line,
    })
}

/// The lines of the `joint`-th `[[joints]]` table: (offset in `text`, line with its
/// ending) of each, from the header's next line to the next table's header.
fn joint_lines(text: &str, joint: usize) -> Vec<(usize, &str)> {
    let mut count = 0;
    let mut inside = false;
    let mut offset = 0;
    let mut out = Vec::new();
    for line in text.split_inclusive('\n') {
        let t = line.trim_start();
        if t.starts_with('[') {
            inside = t.starts_with("[[joints]]") && {
                count += 1;
                count == joint + 1
            };
        } else if inside {
            out.push((offset, line));
        }
        offset += line.len();
    }
    out
}

/// Does `line` set `key` (`key = …`, not `key_more = …`)?
fn sets(line: &str, key: &str) -> bool {
    line.trim_start()
        .strip_prefix(key)
        .is_some_and(|rest| rest.trim_start().starts_with('='))
}

/// The `joint`-th joint's line that sets `key`: its offset in `text` and the line.
fn key_line<'a>(text: &'a str, joint: usize, key: &str) -> Option<(usize, &'a str)> {
    joint_lines(text, joint)
        .into_iter()
        .find(|(_, l)| sets(l, key))
}

/// `text` with the `joint`-th joint's `key = …` line made `key = value`: the old line
/// kept above it as a comment, or, where the joint has none, the line added after its
/// table's last line that sets a key.
pub fn set_line(text: &str, joint: usize, key: &str, value: &str) -> Result<String, String> {
    let lines = joint_lines(text, joint);
    let keyed = |l: &str| {
        let t = l.trim_start();
        !t.is_empty() && !t.starts_with('#') && t.contains('=')
    };
    let new_line = format!("{key} = {value}");
    let mut out = String::with_capacity(text.len() + 2 * new_line.len());
    if let Some(&(offset, line)) = lines.iter().find(|(_, l)| sets(l, key)) {
        let body = line.trim_end_matches(['\n', '\r']);
        let ending = &line[body.len()..];
        let indent = &body[..body.len() - body.trim_start().len()];
        out.push_str(&text[..offset]);
        out.push_str(&format!(
            "{indent}# nc-send tune: was {}\n{indent}{new_line}{}",
            body.trim_start(),
            if ending.is_empty() { "" } else { ending }
        ));
        out.push_str(&text[offset + line.len()..]);
    } else {
        let &(offset, line) =
            lines.iter().rev().find(|(_, l)| keyed(l)).ok_or_else(|| {
                format!("joints[{joint}]: no such joint table to write {key} into")
            })?;
        let end = offset + line.len();
        out.push_str(&text[..end]);
        if !line.ends_with('\n') {
            out.push('\n');
        }
        out.push_str(&new_line);
        out.push('\n');
        out.push_str(&text[end..]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_joints_gains_change() {
        let text = "a = 1\n[[joints]]\nname = \"X\"\nservo = { kp = 0.1, ki = 1.0, max_output = 2.0 }\n\
                    [[joints]]\nname = \"Y\"\nservo = { law = \"lqg\", kp = 0.1, max_output = 2.0 } # y\n[other]\n";
        let r = rewrite(text, 1, &[("kp", 0.25), ("kd", 1e-4)]).unwrap();
        assert_eq!(
            r.line,
            "servo = { law = \"lqg\", kp = 2.5000e-1, kd = 1.0000e-4, max_output = 2.0 } # y"
        );
        let want = text.replace(
            "servo = { law",
            "# nc-send tune: was servo = { law = \"lqg\", kp = 0.1, max_output = 2.0 } # y\nservo = { law",
        );
        let want = want.replace(
            "kp = 0.1, max_output = 2.0 } # y\n[other]",
            "kp = 2.5000e-1, kd = 1.0000e-4, max_output = 2.0 } # y\n[other]",
        );
        assert_eq!(r.text, want);
        assert!(rewrite(text, 2, &[]).unwrap_err().contains("joints[2]"));
    }

    #[test]
    fn an_lqg_line_is_replaced_where_it_is_or_added_to_its_joint() {
        let text = "[[joints]]\nname = \"A\"\nlqg = { a = 1 }\nlqg_gains = { g = 1 }\n\n\
                    [[joints]]\nname = \"B\"\nlqg_gains = { g = 2 }\n# end\n[other]\nlqg = 3\n";
        let a = set_line(text, 0, "lqg", "{ a = 2 }").unwrap();
        assert_eq!(
            a,
            text.replace(
                "lqg = { a = 1 }\n",
                "# nc-send tune: was lqg = { a = 1 }\nlqg = { a = 2 }\n"
            )
        );
        // B has no `lqg` line (its `lqg_gains` is another key): added after its last
        // key, before the comment and the next table.
        let b = set_line(text, 1, "lqg", "{ a = 4 }").unwrap();
        assert_eq!(
            b,
            text.replace(
                "lqg_gains = { g = 2 }\n# end",
                "lqg_gains = { g = 2 }\nlqg = { a = 4 }\n# end"
            )
        );
        assert!(set_line(text, 2, "lqg", "1")
            .unwrap_err()
            .contains("joints[2]"));
    }
}
