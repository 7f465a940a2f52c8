//! Fuzzing the PLY reader: generated files of every format are read back exactly, and
//! thousands of mutations of them (bit flips, truncations, insertions, lying counts) give
//! either a table or a PlyError -- never a panic, a hang or a huge allocation.
//! Inputs that once broke (or could break) a reader are kept as regression tests below,
//! with headers that lie about their sizes (rejected before any allocation) and files whose
//! vertex element is whole but whose end is not (read with a warning, or an error when
//! strict).

use std::path::Path;

use splat_core::ply::{read_vertex_columns_from_bytes, Column};
use splat_core::CoreError;

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const TYPES: [&str; 16] = [
    "char", "int8", "uchar", "uint8", "short", "int16", "ushort", "uint16", "int", "int32", "uint",
    "uint32", "float", "float32", "double", "float64",
];

/// Bytes of one value of PLY type `ty` (binary, little or big endian) or its ascii text.
fn encode(ty: &str, v: f64, fmt: usize) -> (Vec<u8>, String) {
    macro_rules! enc {
        ($t:ty) => {{
            let x = v as $t;
            let b = if fmt == 2 {
                x.to_be_bytes().to_vec()
            } else {
                x.to_le_bytes().to_vec()
            };
            (b, format!("{x:?}"))
        }};
    }
    match ty {
        "char" | "int8" => enc!(i8),
        "uchar" | "uint8" => enc!(u8),
        "short" | "int16" => enc!(i16),
        "ushort" | "uint16" => enc!(u16),
        "int" | "int32" => enc!(i32),
        "uint" | "uint32" => enc!(u32),
        "float" | "float32" => enc!(f32),
        _ => enc!(f64),
    }
}

/// A random valid PLY file and the f64 values of its vertex properties.
fn generate(rng: &mut Rng) -> (Vec<u8>, Vec<(String, Vec<f64>)>) {
    let fmt = rng.below(3);
    let n = rng.below(12);
    let nprops = 1 + rng.below(6);
    let props: Vec<(String, &str)> = (0..nprops)
        .map(|i| (format!("p{i}"), TYPES[rng.below(TYPES.len())]))
        .collect();
    let faces = rng.below(3);
    let face_first = rng.below(2) == 0;
    let format = ["ascii", "binary_little_endian", "binary_big_endian"][fmt];
    let mut head = format!("ply\nformat {format} 1.0\ncomment fuzz\n");
    let vertex_head = {
        let mut h = format!("element vertex {n}\n");
        for (name, ty) in &props {
            h += &format!("property {ty} {name}\n");
        }
        h
    };
    let face_head = format!("element face {faces}\nproperty list uchar int vertex_indices\n");
    head += &if face_first {
        face_head.clone() + &vertex_head
    } else {
        vertex_head.clone() + &face_head
    };
    head += "end_header\n";

    let mut values: Vec<(String, Vec<f64>)> =
        props.iter().map(|(p, _)| (p.clone(), vec![])).collect();
    let mut vbody = Vec::new();
    for _ in 0..n {
        let mut line = Vec::new();
        for (j, (_, ty)) in props.iter().enumerate() {
            let v = (rng.below(200) as f64) - 100.0
                + if ty.starts_with('f') || ty.starts_with('d') {
                    0.25
                } else {
                    0.0
                };
            let v = if ty.starts_with('u') { v.abs() } else { v };
            let (b, s) = encode(ty, v, fmt);
            values[j].1.push(v);
            vbody.extend(b);
            line.push(s);
        }
        let _ = line;
    }
    // Rebuild ascii vertex data from the recorded values (simpler than streaming it).
    if fmt == 0 {
        vbody.clear();
        for r in 0..n {
            let line: Vec<String> = props
                .iter()
                .enumerate()
                .map(|(j, (_, ty))| encode(ty, values[j].1[r], 0).1)
                .collect();
            vbody.extend((line.join(" ") + "\n").as_bytes());
        }
    }
    let mut fbody = Vec::new();
    for _ in 0..faces {
        let k = rng.below(5);
        if fmt == 0 {
            let idx: Vec<String> = (0..k).map(|i| i.to_string()).collect();
            fbody.extend(format!("{k} {}\n", idx.join(" ")).as_bytes());
        } else {
            fbody.push(k as u8);
            for i in 0..k as i32 {
                fbody.extend(if fmt == 2 {
                    i.to_be_bytes()
                } else {
                    i.to_le_bytes()
                });
            }
        }
    }
    let mut bytes = head.into_bytes();
    if face_first {
        bytes.extend(fbody);
        bytes.extend(vbody);
    } else {
        bytes.extend(vbody);
        bytes.extend(fbody);
    }
    (bytes, values)
}

fn as_f64(c: &Column) -> Vec<f64> {
    match c {
        Column::I8(v) => v.iter().map(|&x| f64::from(x)).collect(),
        Column::U8(v) => v.iter().map(|&x| f64::from(x)).collect(),
        Column::I16(v) => v.iter().map(|&x| f64::from(x)).collect(),
        Column::U16(v) => v.iter().map(|&x| f64::from(x)).collect(),
        Column::I32(v) => v.iter().map(|&x| f64::from(x)).collect(),
        Column::U32(v) => v.iter().map(|&x| f64::from(x)).collect(),
        Column::F32(v) => v.iter().map(|&x| f64::from(x)).collect(),
        Column::F64(v) => v.clone(),
    }
}

type Columns = Vec<(String, Column)>;

/// A strict read: every problem is an error.
fn read(bytes: &[u8]) -> Result<Columns, CoreError> {
    read_vertex_columns_from_bytes(bytes, Path::new("fuzz.ply"), true).map(|t| t.columns)
}

/// A lenient read: the columns and the warnings.
fn read_lenient(bytes: &[u8]) -> Result<(Columns, Vec<String>), CoreError> {
    read_vertex_columns_from_bytes(bytes, Path::new("fuzz.ply"), false)
        .map(|t| (t.columns, t.warnings))
}

#[test]
fn generated_files_read_back_exactly() {
    let mut rng = Rng(0x5eed);
    for case in 0..600 {
        let (bytes, values) = generate(&mut rng);
        let cols = read(&bytes).unwrap_or_else(|e| panic!("case {case}: {e}"));
        assert_eq!(cols.len(), values.len());
        for ((name, col), (want_name, want)) in cols.iter().zip(&values) {
            assert_eq!(name, want_name);
            assert_eq!(&as_f64(col), want, "case {case} property {name}");
        }
    }
}

#[test]
fn mutated_files_never_panic() {
    let mut rng = Rng(0xf00d);
    let mut errors = 0;
    let total = 20_000;
    for _ in 0..total {
        let (mut bytes, _) = generate(&mut rng);
        for _ in 0..1 + rng.below(3) {
            if bytes.is_empty() {
                break;
            }
            let at = rng.below(bytes.len());
            match rng.below(6) {
                0 => bytes[at] ^= 1 << rng.below(8),
                1 => bytes.truncate(at),
                2 => bytes.insert(at, rng.next() as u8),
                3 => {
                    bytes.remove(at);
                }
                4 => bytes[at] = b"0123456789 \n-."[rng.below(14)],
                _ => {
                    // Lie about a count: replace the first digit run after "element".
                    let key = b"element vertex ";
                    if let Some(p) = bytes.windows(key.len()).position(|w| w == key) {
                        let start = p + key.len();
                        let end =
                            start + bytes[start..].iter().position(|&b| b == b'\n').unwrap_or(0);
                        let lie = ["0", "1", "99999999999", "18446744073709551615", "-3", "1e3"]
                            [rng.below(6)];
                        bytes.splice(start..end, lie.bytes());
                    }
                }
            }
        }
        let strict = read(&bytes);
        match &strict {
            Ok(cols) => assert!(cols.iter().all(|(_, c)| c.len() < 1 << 20)),
            Err(CoreError::Ply { .. }) => errors += 1,
            Err(other) => panic!("unexpected error kind: {other}"),
        }
        // Lenient reads accept more, never less, and agree with strict ones where both read.
        match (strict, read_lenient(&bytes)) {
            (Ok(a), Ok((b, warnings))) => {
                assert_eq!(a, b);
                assert!(warnings.is_empty(), "{warnings:?}");
            }
            (Ok(_), Err(e)) => panic!("strict read passed, lenient failed: {e}"),
            (Err(_), Ok((_, warnings))) => assert!(!warnings.is_empty()),
            (Err(_), Err(CoreError::Ply { .. })) => {}
            (Err(_), Err(other)) => panic!("unexpected error kind: {other}"),
        }
    }
    // Most mutations must be caught; a few land in values or comments and stay valid.
    assert!(
        errors > total / 3,
        "only {errors} of {total} mutations were rejected"
    );
}

fn ply_err(bytes: &[u8]) -> String {
    match read(bytes) {
        Err(CoreError::Ply { message, .. }) => message,
        other => panic!("expected a PlyError, got {other:?}"),
    }
}

#[test]
fn regression_cases() {
    // Element count whose byte size overflows usize.
    let m = ply_err(b"ply\nformat binary_little_endian 1.0\nelement vertex 18446744073709551615\nproperty double x\nend_header\n");
    assert!(m.contains("lying header"), "{m}");
    // A list length far past the end of the data (in the face element after the vertices).
    let m = ply_err(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nelement face 1\nproperty list uint int i\nend_header\n\0\0\0\0\xff\xff\xff\xff");
    assert!(m.contains("truncated"), "{m}");
    // A negative list length.
    let m = ply_err(b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty list char float v\nend_header\n\xff");
    assert!(m.contains("negative"), "{m}");
    let m = ply_err(
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list char float v\nend_header\n-1\n",
    );
    assert!(m.contains("list length"), "{m}");
    // end_header at EOF without its newline; NUL and non-UTF-8 bytes in the header.
    assert!(ply_err(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header").contains("end_header"));
    assert!(ply_err(b"ply\nformat ascii 1.0\ncomment \xff\xfe\nend_header\n").contains("not text"));
    assert!(ply_err(
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\0\nend_header\n1\n"
    )
    .contains("name"));
    // A comment indented with multi-byte spaces (slicing by the keyword length once panicked).
    let ok = read("ply\nformat ascii 1.0\n\u{3000}\u{3000}\u{3000}comment \u{e9}t\u{e9}\nelement vertex 1\nproperty float x\nend_header\n1\n".as_bytes());
    assert!(ok.is_ok(), "{ok:?}");
    // Huge vertex count in ascii with no data: no giant allocation, a clear error.
    let m = ply_err(
        b"ply\nformat ascii 1.0\nelement vertex 999999999999\nproperty float x\nend_header\n1\n",
    );
    assert!(m.contains("lying header"), "{m}");
    // Values out of range for their declared type.
    assert!(ply_err(
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty uchar x\nend_header\n256\n"
    )
    .contains("not a valid uchar"));
    assert!(ply_err(
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty char x\nend_header\n1.5\n"
    )
    .contains("not a valid char"));
    // Zero-property vertex element with a large count must not loop forever or allocate.
    let t = read(b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nend_header\n")
        .unwrap();
    assert!(t.is_empty());
}

/// A header claiming `count` rows of `props` float properties (plus a list when `list`),
/// in `format`, followed by `data_len` bytes of data.
fn lying(format: &str, count: u64, props: usize, list: bool, data_len: usize) -> Vec<u8> {
    let mut head = format!("ply\nformat {format} 1.0\nelement vertex {count}\n");
    for i in 0..props {
        head += &format!("property float p{i}\n");
    }
    if list {
        head += "property list uchar int l\n";
    }
    head += "end_header\n";
    let mut bytes = head.into_bytes();
    bytes.extend(vec![b'1'; data_len]);
    bytes
}

#[test]
fn lying_headers_are_rejected_before_allocating() {
    // Claims of up to 2^64 rows of up to thousands of properties, over a few KB of data:
    // each must be a PlyError naming the claim (an allocation of the claimed size would
    // abort the test process instead).
    for format in ["ascii", "binary_little_endian", "binary_big_endian"] {
        for (count, props, list) in [
            (1u64 << 40, 3000, false),
            (1 << 40, 3000, true),
            (u64::MAX, 1, false),
            (1 << 33, 1, true),
            (100_000, 4000, false),
            (1_000_000, 0, true),
        ] {
            let bytes = lying(format, count, props, list, 200_000);
            let m = ply_err(&bytes);
            assert!(
                m.contains("lying header") && m.contains(&count.to_string()),
                "{format} {count} x {props}: {m}"
            );
            assert!(read_lenient(&bytes).is_err());
        }
    }
    // A face element that lies is after the vertex element: no allocation, a warning.
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nelement face 1099511627776\nproperty list uchar int i\nend_header\n".to_vec();
    bytes.extend_from_slice(&1.5f32.to_le_bytes());
    bytes.extend_from_slice(&[3, 0, 0, 0, 0]);
    let (cols, warnings) = read_lenient(&bytes).unwrap();
    assert_eq!(cols[0].1, Column::F32(vec![1.5]));
    assert!(warnings[0].contains("element 'face'"), "{warnings:?}");
}

#[test]
fn problems_after_the_vertex_element_are_warnings_unless_strict() {
    let vertex_ascii = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n";
    let cases: Vec<(Vec<u8>, &str)> = vec![
        // One more row than declared (as MeshLab writes), with and without a face element.
        (
            format!("{vertex_ascii}end_header\n1\n2\n3\n").into_bytes(),
            "more row",
        ),
        (
            format!("{vertex_ascii}element face 1\nproperty list uchar int i\nend_header\n1\n2\n2 0 1\n2 1 0\n")
                .into_bytes(),
            "more row",
        ),
        // A truncated face element, in ascii and binary.
        (
            format!("{vertex_ascii}element face 2\nproperty list uchar int i\nend_header\n1\n2\n3 0 1 1\n")
                .into_bytes(),
            "truncated",
        ),
        (
            format!("{vertex_ascii}element face 1\nproperty list uchar int i\nend_header\n1\n2\n3 0 1\n")
                .into_bytes(),
            "shorter than its length",
        ),
        {
            let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float x\nelement face 1\nproperty list uchar int i\nend_header\n".to_vec();
            b.extend_from_slice(&1.0f32.to_be_bytes());
            b.extend_from_slice(&2.0f32.to_be_bytes());
            b.extend_from_slice(&[3, 0, 0, 0, 0, 0]);
            (b, "truncated")
        },
        // Binary data after the last element.
        {
            let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nend_header\n".to_vec();
            for v in [1.0f32, 2.0, 3.0] {
                b.extend_from_slice(&v.to_le_bytes());
            }
            (b, "after the last element")
        },
        // Non-text bytes in an ascii face element.
        {
            let mut b = format!("{vertex_ascii}element face 1\nproperty list uchar int i\nend_header\n1\n2\n")
                .into_bytes();
            b.extend_from_slice(b"3 0 1 \xff\n");
            (b, "not text")
        },
    ];
    for (bytes, needle) in cases {
        let m = ply_err(&bytes);
        assert!(m.contains(needle), "strict: {m}");
        let (cols, warnings) = read_lenient(&bytes).unwrap_or_else(|e| panic!("{needle}: {e}"));
        assert_eq!(cols, vec![("x".to_string(), Column::F32(vec![1.0, 2.0]))]);
        assert_eq!(warnings.len(), 1);
        assert!(
            warnings[0].starts_with("fuzz.ply: ") && warnings[0].contains(needle),
            "{warnings:?}"
        );
    }
    // Problems in or before the vertex element stay errors when lenient.
    for bytes in [
        format!("{vertex_ascii}end_header\n1\n").into_bytes(),
        b"ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int i\nelement vertex 1\nproperty float x\nend_header\n3 0 1\n1\n".to_vec(),
    ] {
        assert!(read_lenient(&bytes).is_err());
    }
}
