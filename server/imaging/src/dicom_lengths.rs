//! A walk over a DICOM file's element headers that checks every declared value length
//! against the bytes that remain, before dicom-rs reads the file: its parser reserves and
//! zero-fills a value's declared length before reading it, so a 379-byte file declaring a
//! 4 GiB value would make it allocate 4 GiB.

/// Checks `bytes` (a whole DICOM Part 10 file) without allocating: `Ok` when every element
/// with a defined length fits in what follows it (or the file is not DICOM, which the reader
/// then skips); otherwise the element's tag, its declared length and what remains. Datasets
/// in big-endian or deflated transfer syntaxes cannot be walked and are refused.
pub fn check(bytes: &[u8]) -> Result<(), String> {
    // The meta group follows "DICM", after a 128-byte preamble or (as dicom-rs also reads
    // it) with none.
    let mut at = if bytes.len() >= 132 && &bytes[128..132] == b"DICM" {
        132
    } else if bytes.starts_with(b"DICM") {
        4
    } else {
        return Ok(());
    };
    // The file meta group (0002) is explicit VR little endian; its transfer syntax says how
    // the dataset is written.
    let mut syntax = String::new();
    while at + 8 <= bytes.len() && u16::from_le_bytes([bytes[at], bytes[at + 1]]) == 0x0002 {
        let element = u16::from_le_bytes([bytes[at + 2], bytes[at + 3]]);
        let (header, length) = explicit_header(bytes, at)?;
        let start = at + header;
        let end = fits(bytes, start, length, 0x0002, element)?;
        if element == 0x0010 {
            syntax = String::from_utf8_lossy(&bytes[start..end])
                .trim_end_matches(['\0', ' '])
                .to_owned();
        }
        at = end;
    }
    let explicit = match syntax.as_str() {
        "1.2.840.10008.1.2" => false,
        "1.2.840.10008.1.2.2" | "1.2.840.10008.1.2.1.99" => {
            return Err(format!(
                "transfer syntax {syntax} (big endian or a deflated dataset) is not read"
            ));
        }
        _ => true,
    };
    walk(bytes, at, explicit)
}

const UNDEFINED: u32 = 0xFFFF_FFFF;

/// Whether the standard dictionary names `(group,element)` a sequence.
fn is_sequence(group: u16, element: u16) -> bool {
    use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry, VirtualVr};
    dicom_dictionary_std::StandardDataDictionary
        .by_tag(dicom_core::Tag(group, element))
        .is_some_and(|e| matches!(e.vr(), VirtualVr::Exact(dicom_core::VR::SQ)))
}

/// The header size and declared length of an explicit-VR element at `at`.
fn explicit_header(bytes: &[u8], at: usize) -> Result<(usize, u32), String> {
    let short = || format!("an element header at byte {at} is cut short");
    let vr = bytes.get(at + 4..at + 6).ok_or_else(short)?;
    // The VRs with a 2-byte length; any other, an unknown one included (read as UN, as
    // dicom-rs reads it), has 2 reserved bytes and a 4-byte length.
    let short_length = matches!(
        vr,
        b"AE"
            | b"AS"
            | b"AT"
            | b"CS"
            | b"DA"
            | b"DS"
            | b"DT"
            | b"FL"
            | b"FD"
            | b"IS"
            | b"LO"
            | b"LT"
            | b"PN"
            | b"SH"
            | b"SL"
            | b"SS"
            | b"ST"
            | b"TM"
            | b"UI"
            | b"UL"
            | b"US"
    );
    if !short_length {
        let l = bytes.get(at + 8..at + 12).ok_or_else(short)?;
        Ok((12, u32::from_le_bytes([l[0], l[1], l[2], l[3]])))
    } else {
        let l = bytes.get(at + 6..at + 8).ok_or_else(short)?;
        Ok((8, u32::from(u16::from_le_bytes([l[0], l[1]]))))
    }
}

/// Where a value of `length` bytes starting at `start` ends, if it fits in the file.
fn fits(
    bytes: &[u8],
    start: usize,
    length: u32,
    group: u16,
    element: u16,
) -> Result<usize, String> {
    let left = bytes.len().saturating_sub(start);
    if length as usize > left {
        return Err(format!(
            "element ({group:04X},{element:04X}) declares {length} bytes where {left} remain"
        ));
    }
    Ok(start + length as usize)
}

/// Walks the dataset from `at` to the end: sequences and items with a defined length are
/// walked into (their contents are elements); encapsulated pixel data's fragments, and every
/// other value, are stepped over once their length is checked.
fn walk(bytes: &[u8], mut at: usize, explicit: bool) -> Result<(), String> {
    let mut in_pixel_items = false;
    while at + 8 <= bytes.len() {
        let group = u16::from_le_bytes([bytes[at], bytes[at + 1]]);
        let element = u16::from_le_bytes([bytes[at + 2], bytes[at + 3]]);
        if group == 0xFFFE {
            // Item, item delimiter, sequence delimiter: a 4-byte length, no VR.
            let length =
                u32::from_le_bytes([bytes[at + 4], bytes[at + 5], bytes[at + 6], bytes[at + 7]]);
            at += 8;
            match element {
                0xE000 if length != UNDEFINED && in_pixel_items => {
                    at = fits(bytes, at, length, group, element)?;
                }
                0xE000 if length != UNDEFINED => {
                    fits(bytes, at, length, group, element)?;
                }
                0xE0DD => in_pixel_items = false,
                _ => {}
            }
            continue;
        }
        let (header, length, sequence) = if explicit {
            let (header, length) = explicit_header(bytes, at)?;
            (header, length, &bytes[at + 4..at + 6] == b"SQ")
        } else {
            // Implicit VR: the dictionary says which elements are sequences.
            let length =
                u32::from_le_bytes([bytes[at + 4], bytes[at + 5], bytes[at + 6], bytes[at + 7]]);
            (8, length, is_sequence(group, element))
        };
        let start = at + header;
        if length == UNDEFINED {
            // A sequence (or, implicitly, an unknown one) or encapsulated pixel data: its
            // contents are items, walked in turn.
            in_pixel_items = (group, element) == (0x7FE0, 0x0010);
            at = start;
            continue;
        }
        let end = fits(bytes, start, length, group, element)?;
        // A sequence with a defined length holds items: walk into it (its items and their
        // elements are checked as they come).
        at = if sequence { start } else { end };
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(elements: &[u8]) -> Vec<u8> {
        let mut out = vec![0u8; 128];
        out.extend(b"DICM");
        // (0002,0010) UI "1.2.840.10008.1.2.1" (explicit VR little endian), 20 bytes.
        out.extend([0x02, 0x00, 0x10, 0x00, b'U', b'I', 20, 0]);
        out.extend(b"1.2.840.10008.1.2.1\0");
        out.extend(elements);
        out
    }

    #[test]
    fn lengths_past_the_end_are_refused_and_fitting_ones_pass() {
        // (0028,0010) US 2 bytes: fits.
        let ok = file(&[0x28, 0x00, 0x10, 0x00, b'U', b'S', 2, 0, 0, 2]);
        assert_eq!(check(&ok), Ok(()));
        // (7FE0,0010) OB declaring 4 GiB − 2.
        let bomb = file(&[
            0xE0, 0x7F, 0x10, 0x00, b'O', b'B', 0, 0, 0xFE, 0xFF, 0xFF, 0xFF,
        ]);
        let e = check(&bomb).unwrap_err();
        assert!(e.contains("(7FE0,0010) declares 4294967294 bytes"), "{e}");
        // A sequence of undefined length whose item declares more than remains.
        let nested = file(&[
            0x08, 0x00, 0x15, 0x11, b'S', b'Q', 0, 0, 0xFF, 0xFF, 0xFF,
            0xFF, // (0008,1115) SQ
            0xFE, 0xFF, 0x00, 0xE0, 0xFF, 0xFF, 0xFF, 0xFF, // item, undefined
            0x08, 0x00, 0x50, 0x11, b'U', b'I', 0xFF, 0x7F, // (0008,1150) UI 32767 bytes
        ]);
        assert!(check(&nested).unwrap_err().contains("(0008,1150)"));
        // An element with a VR no one knows has a 4-byte length, as dicom-rs reads it.
        let unknown = file(&[0x28, 0x00, 0x54, 0x10, b'L', b'S', 8, 0, 0x10, 0, 0, 0x5C]);
        assert!(check(&unknown).unwrap_err().contains("(0028,1054)"));
        // Not DICOM: left to the reader.
        assert_eq!(check(b"not a dicom file"), Ok(()));
    }
}
