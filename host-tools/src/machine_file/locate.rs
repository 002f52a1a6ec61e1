//! Where in a machine file's text a field is written: the line of the field an error
//! names, and the field written at a line (for serde's refusals, which carry only a
//! position).

/// The line of the field that an error message names first (`joints[2] (Z).max_velocity:
/// …`, `axes.X.max_accel: …`, `hexapod.base_angles: …`, `home[3]: …`), 1-based: the
/// line of its key within its table, or the table's header when the key is not
/// written (a default, or a whole section that is wrong).
pub(super) fn line_of_field(text: &str, message: &str) -> Option<usize> {
    let path = message.split(": ").next()?;
    let strip = |k: &str| k.split('[').next().unwrap_or(k).trim().to_string();
    // (table, index among tables of that name, key)
    let (table, index, key): (Option<String>, usize, Option<String>) = if let Some((array, rest)) =
        ["joints", "tools"]
            .iter()
            .find_map(|a| path.strip_prefix(&format!("{a}[")).map(|r| (*a, r)))
    {
        let j: usize = rest.split(']').next()?.parse().ok()?;
        let key = rest.split(").").nth(1).or_else(|| rest.split("].").nth(1));
        (Some(array.into()), j, key.map(strip))
    } else {
        let parts: Vec<&str> = path.split('.').collect();
        match parts.as_slice() {
            ["axes", axis, key, ..] => (Some(format!("axes.{axis}")), 0, Some(strip(key))),
            ["axes", axis] => (Some(format!("axes.{axis}")), 0, None),
            [t @ ("h4_table" | "hexapod" | "motion" | "contour"), key, ..] => {
                (Some((*t).into()), 0, Some(strip(key)))
            }
            [t @ ("h4_table" | "hexapod" | "motion" | "contour" | "joints")] => {
                (Some((*t).into()), 0, None)
            }
            [key] if !key.contains(' ') => (None, 0, Some(strip(key))),
            _ => return None,
        }
    };
    let mut current: Option<String> = None;
    let mut seen = std::collections::HashMap::<String, usize>::new();
    let mut header_line = None;
    for (n, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.starts_with('[') {
            let name = line
                .trim_matches(|c| c == '[' || c == ']')
                .trim()
                .to_string();
            let k = seen.entry(name.clone()).or_insert(0);
            let this = *k;
            *k += 1;
            let here = table.as_deref() == Some(name.as_str()) && this == index;
            if here {
                header_line = Some(n + 1);
            } else if header_line.is_some() && current.is_some() {
                // Past the table without finding the key.
                break;
            }
            current = here.then_some(name);
            continue;
        }
        let in_table = match &table {
            None => current.is_none() && seen.is_empty(),
            Some(_) => current.is_some(),
        };
        if let (true, Some(key)) = (in_table, &key) {
            let k = line.split('=').next().unwrap_or("").trim();
            if line.contains('=') && k == key {
                return Some(n + 1);
            }
        }
    }
    header_line
}

pub(super) fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before
        .rfind('\n')
        .map_or(before.len(), |p| before.len() - p - 1)
        + 1;
    (line, col)
}

/// The dotted name of the field written at byte `offset` of `text` (`contour.mode`,
/// `joints[2].drive`, `kinematics`): its key, within the table above it.
pub(super) fn field_at(text: &str, offset: usize) -> Option<String> {
    let before = &text[..offset.min(text.len())];
    let line_start = before.rfind('\n').map_or(0, |p| p + 1);
    let line = text[line_start..].lines().next()?;
    let key = line.split('=').next()?.trim();
    if key.is_empty() || !line.contains('=') {
        return None;
    }
    let mut table: Option<String> = None;
    let mut seen = std::collections::HashMap::<String, usize>::new();
    for raw in before[..line_start].lines() {
        let l = raw.split('#').next().unwrap_or("").trim();
        if l.starts_with("[[") {
            let name = l.trim_matches(|c| c == '[' || c == ']').trim().to_string();
            let n = seen.entry(name.clone()).or_insert(0);
            table = Some(format!("{name}[{n}]"));
            *n += 1;
        } else if l.starts_with('[') {
            table = Some(l.trim_matches(|c| c == '[' || c == ']').trim().to_string());
        }
    }
    Some(match table {
        Some(t) => format!("{t}.{key}"),
        None => key.to_string(),
    })
}
