//! `nc-send tune --write`: the machine file with one joint's `servo = { … }` gains
//! rewritten in place (kp, ki, kd, kvff, kaff), under a comment that gives the old
//! line; every other byte of the file is kept.

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
    let mut count = 0;
    let mut inside = false;
    let mut at = None;
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        let t = line.trim_start();
        if t.starts_with('[') {
            inside = t.starts_with("[[joints]]") && {
                count += 1;
                count == joint + 1
            };
        } else if inside && t.starts_with("servo") && t[5..].trim_start().starts_with('=') {
            at = Some((offset, line));
            break;
        }
        offset += line.len();
    }
    let (offset, line) =
        at.ok_or_else(|| format!("joints[{joint}]: no `servo = {{ … }}` line to rewrite"))?;
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
}
