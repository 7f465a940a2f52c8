//! Decoding ascii PLY data: one row per non-empty line, values separated by whitespace.

use super::header::{Element, Property};
use super::read::{empty_column, scalar_names, Decoded, Failure, Lenience};
use super::Column;

fn parse_int(token: &str) -> Option<i64> {
    token.parse::<i64>().ok().or_else(|| {
        // Some writers print integers as "3.0".
        let f = token.parse::<f64>().ok()?;
        (f.fract() == 0.0 && f.abs() < 9.0e15).then_some(f as i64)
    })
}

fn push_ascii(column: &mut Column, token: &str) -> Option<()> {
    macro_rules! int {
        ($v:expr) => {
            $v.push(parse_int(token)?.try_into().ok()?)
        };
    }
    match column {
        Column::I8(v) => int!(v),
        Column::U8(v) => int!(v),
        Column::I16(v) => int!(v),
        Column::U16(v) => int!(v),
        Column::I32(v) => int!(v),
        Column::U32(v) => int!(v),
        Column::F32(v) => v.push(token.parse().ok()?),
        Column::F64(v) => v.push(token.parse().ok()?),
    }
    Some(())
}

/// The longest prefix of whole lines that is UTF-8, and where the first non-text byte is.
fn text_lines(data: &[u8]) -> (&str, Option<usize>) {
    match std::str::from_utf8(data) {
        Ok(text) => (text, None),
        Err(e) => {
            let valid = &data[..e.valid_up_to()];
            // A line cut by the bad byte is not a whole row: drop it.
            let whole = valid.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
            (
                std::str::from_utf8(&valid[..whole]).unwrap_or_default(),
                Some(e.valid_up_to()),
            )
        }
    }
}

/// Reads every element up to and including `vertex` (problems there are errors); elements
/// after it and extra rows at the end go through `lenience`.
pub(super) fn read_ascii(
    data: &[u8],
    elements: &[Element],
    vertex: usize,
    lenience: &mut Lenience,
) -> Result<Decoded, Failure> {
    let (text, not_text) = text_lines(data);
    let not_text_error = |at: usize| format!("ascii data is not text (byte {at})");
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let mut out = Decoded::Columns(Vec::new());
    for (i, element) in elements.iter().enumerate() {
        // The header's counts were checked against the data length (claims.rs), so the
        // capacity is bounded by the file.
        let mut cols: Vec<Column> = if i == vertex {
            scalar_names(element)
                .map(|(_, ty)| empty_column(ty, element.count))
                .collect::<Result<_, _>>()?
        } else {
            Vec::new()
        };
        let keep = (i == vertex).then_some(&mut cols);
        if let Err(problem) = read_rows(&mut lines, element, keep) {
            let problem = not_text.map_or(problem, not_text_error);
            if i <= vertex {
                return Err(problem.into());
            }
            lenience.past_vertex(problem)?;
            return Ok(out);
        }
        if i == vertex {
            out = Decoded::Columns(cols);
        }
    }
    if let Some(at) = not_text {
        lenience.past_vertex(not_text_error(at))?;
    } else if let Some((line_no, _)) = lines.next() {
        let extra = 1 + lines.count();
        lenience.past_vertex(format!(
            "data line {}: {extra} more row(s) than the header's element counts declare",
            line_no + 1
        ))?;
    }
    Ok(out)
}

/// Reads the rows of one element, pushing its scalars into `cols` when given.
fn read_rows<'a>(
    lines: &mut impl Iterator<Item = (usize, &'a str)>,
    element: &Element,
    mut cols: Option<&mut Vec<Column>>,
) -> Result<(), String> {
    for row in 0..element.count {
        let (line_no, line) = lines.next().ok_or_else(|| {
            format!(
                "truncated file: element '{}' declares {} rows but the data has {row}",
                element.name, element.count
            )
        })?;
        let at = |what: String| {
            format!(
                "data line {}: element '{}' row {row}: {what}",
                line_no + 1,
                element.name
            )
        };
        let mut tokens = line.split_ascii_whitespace();
        let mut scalar = 0;
        for p in &element.properties {
            let token = tokens
                .next()
                .ok_or_else(|| at(format!("missing value for '{}'", p.name())))?;
            match p {
                Property::Scalar { name, ty } => {
                    if let Some(cols) = cols.as_deref_mut() {
                        push_ascii(&mut cols[scalar], token).ok_or_else(|| {
                            at(format!(
                                "'{token}' is not a valid {} for '{name}'",
                                ty.ply_name()
                            ))
                        })?;
                        scalar += 1;
                    } else if token.parse::<f64>().is_err() {
                        return Err(at(format!("'{token}' is not a number")));
                    }
                }
                Property::List { name, .. } => {
                    let n = parse_int(token)
                        .and_then(|n| usize::try_from(n).ok())
                        .ok_or_else(|| at(format!("invalid list length '{token}' for '{name}'")))?;
                    for _ in 0..n {
                        let item = tokens.next().ok_or_else(|| {
                            at(format!("list '{name}' is shorter than its length {n}"))
                        })?;
                        if item.parse::<f64>().is_err() {
                            return Err(at(format!("'{item}' in list '{name}' is not a number")));
                        }
                    }
                }
            }
        }
        if let Some(extra) = tokens.next() {
            return Err(at(format!("unexpected extra value '{extra}'")));
        }
    }
    Ok(())
}
