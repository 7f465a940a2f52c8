//! The PLY text header: format, elements and their properties.

use std::collections::HashSet;
use std::path::Path;

use crate::{CoreError, CoreResult};

/// A header longer than this without `end_header` is not a PLY header.
pub(super) const MAX_HEADER_BYTES: usize = 1 << 20;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScalarType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl ScalarType {
    /// Both spellings of the PLY specification (`uchar` and `uint8`, ...).
    pub fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    /// The name written to headers (the original spelling, understood by every reader).
    pub fn ply_name(self) -> &'static str {
        match self {
            Self::I8 => "char",
            Self::U8 => "uchar",
            Self::I16 => "short",
            Self::U16 => "ushort",
            Self::I32 => "int",
            Self::U32 => "uint",
            Self::F32 => "float",
            Self::F64 => "double",
        }
    }

    pub fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    pub fn is_float(self) -> bool {
        matches!(self, Self::F32 | Self::F64)
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Property {
    Scalar {
        name: String,
        ty: ScalarType,
    },
    List {
        name: String,
        count_ty: ScalarType,
        item_ty: ScalarType,
    },
}

impl Property {
    pub fn name(&self) -> &str {
        match self {
            Property::Scalar { name, .. } | Property::List { name, .. } => name,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Element {
    pub name: String,
    pub count: usize,
    pub properties: Vec<Property>,
}

impl Element {
    /// Bytes per row in a binary file when every property is a scalar.
    pub fn fixed_row_size(&self) -> Option<usize> {
        self.properties
            .iter()
            .map(|p| match p {
                Property::Scalar { ty, .. } => Some(ty.size()),
                Property::List { .. } => None,
            })
            .sum()
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    pub format: Format,
    pub elements: Vec<Element>,
    pub comments: Vec<String>,
    /// Offset of the first data byte (just after `end_header` and its line break).
    pub data_start: usize,
}

/// Parses the header at the start of `bytes`; `path` only names the file in errors.
pub fn parse_header(bytes: &[u8], path: &Path) -> CoreResult<Header> {
    let err = |msg: String| CoreError::ply(path, msg);
    if !bytes.starts_with(b"ply\n") && !bytes.starts_with(b"ply\r\n") {
        return Err(err(
            "not a PLY file (it does not start with the line 'ply')".into(),
        ));
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut comments = Vec::new();
    // Names seen so far (sets: a header may declare a hundred thousand properties).
    let mut element_names: HashSet<String> = HashSet::new();
    let mut property_names: HashSet<String> = HashSet::new();
    let mut pos = 0;
    let mut line_no = 0;
    loop {
        let rest = &bytes[pos..];
        let Some(nl) = rest.iter().position(|&b| b == b'\n') else {
            return Err(err(
                if pos >= MAX_HEADER_BYTES || bytes.len() >= MAX_HEADER_BYTES {
                    "header has no 'end_header' line in its first MiB".into()
                } else {
                    "truncated header: no 'end_header' line".into()
                },
            ));
        };
        if pos + nl > MAX_HEADER_BYTES {
            return Err(err(
                "header has no 'end_header' line in its first MiB".into()
            ));
        }
        line_no += 1;
        let raw = &rest[..nl];
        pos += nl + 1;
        let line = std::str::from_utf8(raw)
            .map_err(|_| err(format!("header line {line_no} is not text")))?
            .trim_end_matches('\r');
        let words: Vec<&str> = line.split_whitespace().collect();
        let Some(&keyword) = words.first() else {
            continue;
        };
        match keyword {
            "ply" if line_no == 1 => {}
            "comment" | "obj_info" => {
                comments.push(line.trim_start()[keyword.len()..].trim().to_string());
            }
            "format" => {
                if words.len() != 3 {
                    return Err(err(format!("header line {line_no}: malformed '{line}'")));
                }
                format = Some(match words[1] {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::BinaryLittleEndian,
                    "binary_big_endian" => Format::BinaryBigEndian,
                    other => return Err(err(format!("unknown PLY format '{other}'"))),
                });
                if words[2] != "1.0" {
                    return Err(err(format!("unsupported PLY version '{}'", words[2])));
                }
            }
            "element" => {
                if words.len() != 3 {
                    return Err(err(format!("header line {line_no}: malformed '{line}'")));
                }
                let count: usize = words[2].parse().map_err(|_| {
                    err(format!(
                        "element '{}' has an invalid count '{}'",
                        words[1], words[2]
                    ))
                })?;
                if !element_names.insert(words[1].to_string()) {
                    return Err(err(format!("element '{}' is declared twice", words[1])));
                }
                property_names.clear();
                elements.push(Element {
                    name: words[1].to_string(),
                    count,
                    properties: Vec::new(),
                });
            }
            "property" => {
                let element = elements.last_mut().ok_or_else(|| {
                    err(format!(
                        "header line {line_no}: property before any element"
                    ))
                })?;
                let bad_type = |t: &str| err(format!("unknown property type '{t}' in '{line}'"));
                let property = match words.as_slice() {
                    ["property", "list", count_ty, item_ty, name] => {
                        let count_ty =
                            ScalarType::parse(count_ty).ok_or_else(|| bad_type(count_ty))?;
                        if count_ty.is_float() {
                            return Err(err(format!(
                                "list count type must be an integer in '{line}'"
                            )));
                        }
                        Property::List {
                            name: name.to_string(),
                            count_ty,
                            item_ty: ScalarType::parse(item_ty).ok_or_else(|| bad_type(item_ty))?,
                        }
                    }
                    ["property", ty, name] => Property::Scalar {
                        name: name.to_string(),
                        ty: ScalarType::parse(ty).ok_or_else(|| bad_type(ty))?,
                    },
                    _ => return Err(err(format!("header line {line_no}: malformed '{line}'"))),
                };
                if property.name().chars().any(char::is_control) {
                    return Err(err(format!(
                        "header line {line_no}: property name {:?} has control characters",
                        property.name()
                    )));
                }
                if !property_names.insert(property.name().to_string()) {
                    return Err(err(format!(
                        "property '{}' of element '{}' is declared twice",
                        property.name(),
                        element.name
                    )));
                }
                element.properties.push(property);
            }
            "end_header" => break,
            other => {
                return Err(err(format!(
                    "header line {line_no}: unknown keyword '{other}'"
                )))
            }
        }
    }
    let format = format.ok_or_else(|| err("header has no 'format' line".into()))?;
    Ok(Header {
        format,
        elements,
        comments,
        data_start: pos,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> CoreResult<Header> {
        parse_header(text.as_bytes(), Path::new("t.ply"))
    }

    #[test]
    fn parses_elements_aliases_and_lists() {
        let h = parse(
            "ply\nformat binary_little_endian 1.0\ncomment made by a test\nelement vertex 3\n\
             property float32 x\nproperty uchar red\nelement face 1\n\
             property list uint8 int vertex_indices\nend_header\n",
        )
        .unwrap();
        assert_eq!(h.format, Format::BinaryLittleEndian);
        assert_eq!(h.comments, vec!["made by a test".to_string()]);
        assert_eq!(h.elements[0].count, 3);
        assert_eq!(h.elements[0].fixed_row_size(), Some(5));
        assert_eq!(h.elements[1].fixed_row_size(), None);
        assert!(matches!(
            h.elements[1].properties[0],
            Property::List {
                count_ty: ScalarType::U8,
                item_ty: ScalarType::I32,
                ..
            }
        ));
    }

    #[test]
    fn crlf_header_is_accepted() {
        let h = parse(
            "ply\r\nformat ascii 1.0\r\nelement vertex 0\r\nproperty float x\r\nend_header\r\n",
        )
        .unwrap();
        assert_eq!(h.format, Format::Ascii);
        assert_eq!(h.elements[0].properties.len(), 1);
    }

    #[test]
    fn malformed_headers_are_named() {
        let cases = [
            ("plyx\n", "not a PLY file"),
            ("ply\nformat ascii 1.0\nelement vertex 1\n", "no 'end_header'"),
            ("ply\nelement vertex 1\nend_header\n", "no 'format'"),
            ("ply\nformat ascii 2.0\nend_header\n", "version"),
            ("ply\nformat ascii 1.0\nelement vertex -1\nend_header\n", "invalid count"),
            ("ply\nformat ascii 1.0\nproperty float x\nend_header\n", "before any element"),
            ("ply\nformat ascii 1.0\nelement v 1\nproperty float128 x\nend_header\n", "unknown property type"),
            ("ply\nformat ascii 1.0\nelement v 1\nproperty float x\nproperty float x\nend_header\n", "twice"),
            ("ply\nformat ascii 1.0\nelement v 1\nproperty list float int i\nend_header\n", "count type"),
            ("ply\nformat ascii 1.0\nbanana\nend_header\n", "unknown keyword"),
        ];
        for (text, needle) in cases {
            let msg = parse(text).unwrap_err().to_string();
            assert!(msg.contains(needle), "{text:?}: {msg}");
        }
    }
}
