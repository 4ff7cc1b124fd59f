//! The check that no DICOM element declares more bytes than its file holds, made before
//! dicom-rs reads the file for real: its parser reserves and zero-fills a value's declared
//! length before reading it, so a 379-byte file declaring a 4 GiB value would make it
//! allocate 4 GiB.
//!
//! The check runs dicom-rs's own decoders (the file meta group's explicit VR little endian
//! header decoder, then the dataset reader for the file's transfer syntax) over the bytes,
//! and looks at every header before the value behind it is read: the file is walked exactly
//! as dicom-rs will walk it (odd lengths, numeric values whose length is not a multiple of
//! their size, implicit VR looked up in the dictionary), so no element can be read with a
//! length the check did not see.

use std::cell::Cell;
use std::io::Read;
use std::rc::Rc;

use dicom_core::{Length, Tag};
use dicom_encoding::decode::Decode;
use dicom_encoding::decode::explicit_le::ExplicitVRLittleEndianDecoder;
use dicom_encoding::transfer_syntax::{Codec, TransferSyntaxIndex};
use dicom_parser::dataset::{DataSetReader, DataToken, read::DataSetReaderOptions};
use dicom_transfer_syntax_registry::TransferSyntaxRegistry;

/// Checks `bytes` (a whole DICOM Part 10 file) with dicom-rs's own decoders, allocating at
/// most what the file holds: `Ok(Some(stream))` with the stream from the "DICM" magic code
/// on (what [`dicom_object::OpenFileOptions::from_reader`] reads) when every element with a
/// defined length fits in what follows it; `Ok(None)` when the file is not DICOM; otherwise
/// the element's tag, its declared length and what remains. A file dicom-rs cannot parse
/// passes (its reader then fails on it without allocating more than the check did). A
/// deflated dataset is inflated once, within `max_inflated_bytes`, to be walked.
pub fn checked(bytes: &[u8]) -> Result<Option<&[u8]>, String> {
    // Where dicom-rs finds the magic code: after a 128-byte preamble, or with none.
    let stream = if bytes.len() >= 132 && &bytes[128..132] == b"DICM" {
        &bytes[128..]
    } else if bytes.starts_with(b"DICM") {
        bytes
    } else {
        return Ok(None);
    };
    let Some((syntax, dataset)) = meta_group(&stream[4..])? else {
        return Ok(Some(stream));
    };
    let Some(ts) = TransferSyntaxRegistry.get(&syntax) else {
        return Ok(Some(stream)); // dicom-rs refuses an unknown transfer syntax
    };
    match ts.codec() {
        Codec::Dataset(Some(_)) => {
            // Deflated explicit VR little endian: walk what it inflates to.
            let inflated = cathlab_anatomy::io::limits::inflate_bounded(
                flate2::read::DeflateDecoder::new(dataset),
                None,
            )
            .map_err(|e| format!("the deflated dataset: {e}"))?;
            walk_dataset(&inflated, ts)?;
        }
        Codec::Dataset(None) => {} // a dataset codec dicom-rs does not have: refused by it
        _ => walk_dataset(dataset, ts)?,
    }
    Ok(Some(stream))
}

/// A reader over a byte slice whose position is shared with the walk, so the bytes left
/// are known while dicom-rs's decoder owns the reader.
struct Counted<'a> {
    bytes: &'a [u8],
    at: Rc<Cell<usize>>,
}

impl<'a> Counted<'a> {
    fn new(bytes: &'a [u8]) -> (Self, Rc<Cell<usize>>) {
        let at = Rc::new(Cell::new(0));
        (
            Self {
                bytes,
                at: at.clone(),
            },
            at,
        )
    }
}

impl Read for Counted<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let at = self.at.get();
        let n = buf.len().min(self.bytes.len() - at);
        buf[..n].copy_from_slice(&self.bytes[at..at + n]);
        self.at.set(at + n);
        Ok(n)
    }
}

/// Refuses a value of `length` bytes (undefined lengths pass) at a point where `left` bytes
/// remain.
fn fits(tag: Tag, length: Length, left: usize) -> Result<(), String> {
    match length.get() {
        Some(length) if length as usize > left => Err(format!(
            "element ({:04X},{:04X}) declares {length} bytes where {left} remain",
            tag.group(),
            tag.element()
        )),
        _ => Ok(()),
    }
}

/// Walks the file meta group as `dicom_object`'s `FileMetaTable` reads it (the group length
/// element first, then elements until that many bytes are read), checking each length; the
/// transfer syntax UID and the dataset's bytes, or `None` where dicom-rs would refuse the
/// group before reading any value.
fn meta_group(bytes: &[u8]) -> Result<Option<(String, &[u8])>, String> {
    let decoder = ExplicitVRLittleEndianDecoder::default();
    let (mut reader, at) = Counted::new(bytes);
    let Ok((header, _)) = decoder.decode_header(&mut reader) else {
        return Ok(None);
    };
    if header.tag != Tag(0x0002, 0x0000) || header.len != Length(4) {
        return Ok(None);
    }
    let mut value = [0u8; 4];
    if reader.read_exact(&mut value).is_err() {
        return Ok(None);
    }
    let group_length = u32::from_le_bytes(value);
    let mut read = 0u32;
    let mut syntax = String::new();
    while read < group_length {
        let Ok((header, header_bytes)) = decoder.decode_header(&mut reader) else {
            return Ok(None);
        };
        let Some(length) = header.len.get() else {
            return Ok(None);
        };
        fits(header.tag, header.len, bytes.len() - at.get())?;
        let start = at.get();
        let end = start + length as usize;
        if header.tag == Tag(0x0002, 0x0010) {
            syntax = String::from_utf8_lossy(&bytes[start..end]).into_owned();
        }
        at.set(end);
        read = read
            .saturating_add(header_bytes as u32)
            .saturating_add(length);
    }
    Ok(Some((syntax, &bytes[at.get()..])))
}

/// Reads the dataset token by token with dicom-rs's reader for `ts`, checking every element
/// and item header's length before the reader reads the value behind it.
fn walk_dataset(
    bytes: &[u8],
    ts: &dicom_encoding::transfer_syntax::TransferSyntax,
) -> Result<(), String> {
    let (reader, at) = Counted::new(bytes);
    // The options `dicom_object` reads a file with.
    let options = DataSetReaderOptions::default();
    let Ok(tokens) = DataSetReader::new_with_ts_options(reader, ts, options) else {
        return Ok(());
    };
    for token in tokens {
        let left = bytes.len() - at.get();
        match token {
            Ok(DataToken::ElementHeader(header)) => fits(header.tag, header.len, left)?,
            Ok(DataToken::SequenceStart { tag, len }) => fits(tag, len, left)?,
            Ok(DataToken::ItemStart { len }) => fits(Tag(0xFFFE, 0xE000), len, left)?,
            Ok(_) => {}
            // dicom-rs stops at the same error when it reads the file.
            Err(_) => break,
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Part 10 file: preamble, magic code, a meta group declaring `syntax`, then `dataset`.
    fn file(syntax: &str, dataset: &[u8]) -> Vec<u8> {
        let mut uid = syntax.as_bytes().to_vec();
        if uid.len() % 2 == 1 {
            uid.push(0);
        }
        let mut meta = vec![0x02, 0x00, 0x10, 0x00, b'U', b'I', uid.len() as u8, 0];
        meta.extend(&uid);
        let mut out = vec![0u8; 128];
        out.extend(b"DICM");
        out.extend([0x02, 0x00, 0x00, 0x00, b'U', b'L', 4, 0]);
        out.extend((meta.len() as u32).to_le_bytes());
        out.extend(meta);
        out.extend(dataset);
        out
    }

    const EXPLICIT: &str = "1.2.840.10008.1.2.1";

    #[test]
    fn lengths_past_the_end_are_refused_and_fitting_ones_pass() {
        // (0028,0010) US 2 bytes: fits.
        let ok = file(EXPLICIT, &[0x28, 0x00, 0x10, 0x00, b'U', b'S', 2, 0, 0, 2]);
        assert_eq!(checked(&ok), Ok(Some(&ok[128..])));
        // (7FE0,0010) OB declaring 4 GiB − 2.
        let bomb = file(
            EXPLICIT,
            &[
                0xE0, 0x7F, 0x10, 0x00, b'O', b'B', 0, 0, 0xFE, 0xFF, 0xFF, 0xFF,
            ],
        );
        let e = checked(&bomb).unwrap_err();
        assert!(e.contains("(7FE0,0010) declares 4294967294 bytes"), "{e}");
        // A sequence of undefined length whose item holds an element declaring too much.
        let nested = file(
            EXPLICIT,
            &[
                0x08, 0x00, 0x15, 0x11, b'S', b'Q', 0, 0, 0xFF, 0xFF, 0xFF,
                0xFF, // (0008,1115) SQ
                0xFE, 0xFF, 0x00, 0xE0, 0xFF, 0xFF, 0xFF, 0xFF, // item, undefined
                0x08, 0x00, 0x50, 0x11, b'U', b'I', 0xFF, 0x7F, // (0008,1150) UI 32767 bytes
            ],
        );
        assert!(checked(&nested).unwrap_err().contains("(0008,1150)"));
        // An implicit-VR dataset: lengths are 4 bytes after the tag.
        let implicit = file(
            "1.2.840.10008.1.2",
            &[0x28, 0x00, 0x10, 0x00, 0x00, 0x00, 0x00, 0x40],
        );
        assert!(checked(&implicit).unwrap_err().contains("(0028,0010)"));
        // A meta group element declaring more than the file.
        let mut meta = file(EXPLICIT, &[]);
        meta[128 + 4 + 12 + 6] = 0xFF;
        assert!(checked(&meta).unwrap_err().contains("(0002,0010)"));
        // Not DICOM: left to the reader.
        assert_eq!(checked(b"not a dicom file"), Ok(None));
    }

    /// The fuzzer's finding: an SL value of 6 bytes is read by dicom-rs as one 4-byte value,
    /// after which it reads the file 2 bytes off (here, into a value declared 1.4 GB long),
    /// where a walk stepping over the declared 6 bytes sees other headers.
    #[test]
    fn a_numeric_value_of_odd_size_is_walked_as_dicom_rs_reads_it() {
        let mut dataset = vec![0x08, 0x00, 0x02, 0x01, b'S', b'L', 6, 0];
        // The declared 6 bytes: dicom-rs takes "SECT" and reads the next header from "RA":
        // tag (4152,0008), VR OB, length 0x55AA55AA.
        dataset.extend(b"SECTRA");
        dataset.extend([0x08, 0x00, b'O', b'B', 0, 0, 0xAA, 0x55, 0xAA, 0x55]);
        let bytes = file(EXPLICIT, &dataset);
        let e = checked(&bytes).unwrap_err();
        assert!(e.contains("declares 1437226410 bytes"), "{e}");
    }

    #[test]
    fn a_deflated_dataset_is_walked_inflated() {
        use std::io::Write;
        let plain = [
            0xE0, 0x7F, 0x10, 0x00, b'O', b'B', 0, 0, 0x00, 0x00, 0x00, 0x10,
        ];
        let mut deflate =
            flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::default());
        deflate.write_all(&plain).unwrap();
        let bytes = file("1.2.840.10008.1.2.1.99", &deflate.finish().unwrap());
        assert!(checked(&bytes).unwrap_err().contains("(7FE0,0010)"));
    }
}
