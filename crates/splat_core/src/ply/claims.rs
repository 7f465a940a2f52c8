//! The header's claimed sizes against the data that follows it, checked before anything is
//! allocated: a short file whose header claims 2^40 rows of a thousand properties is
//! rejected at once instead of reserving terabytes.
//!
//! Each row needs at least a known number of bytes: in binary files the sum of its scalar
//! sizes plus the length field of each list (an empty list); in ascii files a character
//! and a separator (space or line break) per value. The claims of every element up to the
//! one being read must fit in the data.

use super::header::{Element, Format, Property};
use crate::error::human_bytes;

/// The fewest bytes one row of `element` can take in `format`.
pub(super) fn min_row_bytes(element: &Element, format: Format) -> u128 {
    match format {
        Format::Ascii => 2 * element.properties.len() as u128,
        Format::BinaryLittleEndian | Format::BinaryBigEndian => element
            .properties
            .iter()
            .map(|p| match p {
                Property::Scalar { ty, .. } => ty.size() as u128,
                Property::List { count_ty, .. } => count_ty.size() as u128,
            })
            .sum(),
    }
}

/// Checks that `elements`, in order, can fit in `data_len` bytes.
pub(super) fn check_claimed_sizes(
    elements: &[Element],
    format: Format,
    data_len: usize,
) -> Result<(), String> {
    // u128: a count below 2^64 times a row below 2^24 bytes cannot overflow.
    let mut needed: u128 = 0;
    for element in elements {
        let row = min_row_bytes(element, format);
        needed += element.count as u128 * row;
        // The last ascii row may end without its line break.
        let slack = u128::from(format == Format::Ascii && needed > 0);
        if needed - slack > data_len as u128 {
            let per_value = if format == Format::Ascii {
                " (a character and a separator per value)"
            } else {
                ""
            };
            return Err(format!(
                "truncated file or lying header: element '{}' declares {} rows of at least \
                 {row} bytes each{per_value}, {} with the elements before it, but only {} \
                 of data follow the header",
                element.name,
                element.count,
                human_bytes(needed),
                human_bytes(data_len as u128),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ply::ScalarType;

    fn element(count: usize, props: usize, list: bool) -> Element {
        let mut properties: Vec<Property> = (0..props)
            .map(|i| Property::Scalar {
                name: format!("p{i}"),
                ty: ScalarType::F32,
            })
            .collect();
        if list {
            properties.push(Property::List {
                name: "l".into(),
                count_ty: ScalarType::U8,
                item_ty: ScalarType::I32,
            });
        }
        Element {
            name: "vertex".into(),
            count,
            properties,
        }
    }

    #[test]
    fn exact_sizes_pass_and_one_byte_less_fails() {
        let bin = Format::BinaryLittleEndian;
        assert!(check_claimed_sizes(&[element(10, 3, false)], bin, 120).is_ok());
        assert!(check_claimed_sizes(&[element(10, 3, false)], bin, 119).is_err());
        assert!(check_claimed_sizes(&[element(10, 3, true)], bin, 130).is_ok());
        assert!(check_claimed_sizes(&[element(10, 3, true)], bin, 129).is_err());
        // "1 2 3\n" per row, the last line break optional.
        assert!(check_claimed_sizes(&[element(10, 3, false)], Format::Ascii, 59).is_ok());
        assert!(check_claimed_sizes(&[element(10, 3, false)], Format::Ascii, 58).is_err());
    }

    #[test]
    fn huge_claims_are_named_without_overflow() {
        for format in [Format::Ascii, Format::BinaryBigEndian] {
            let e = element(usize::MAX, 5000, true);
            let msg = check_claimed_sizes(&[e], format, 243_000).unwrap_err();
            assert!(msg.contains("lying header"), "{msg}");
            assert!(msg.contains(&usize::MAX.to_string()), "{msg}");
        }
    }
}
