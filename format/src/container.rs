//! The container: a fixed header, a section table and 16-byte-aligned sections.
//!
//! ```text
//! offset  size  field
//!  0       8    magic  "\x89MLTBK\r\n"   (a PNG-style signature: catches text-mode mangling)
//!  8       2    format major version (readers reject other majors)
//! 10       2    format minor version (see the version rule below)
//! 12       4    flags (reserved, 0)
//! 16       4    header length in bytes (fixed part + section table, multiple of 16)
//! 20       4    section count
//! 24       8    file length in bytes
//! 32       8    xxh3-64 of the payload (bytes header_len..file_len)
//! 40       8    xxh3-64 of the header with this field zeroed
//! 48       8    input key: xxh3-64 of everything the bake's result depends on (scene bytes,
//!               parameters, tool version), 0 if unknown (1.2 and later)
//! 56       8    reserved, 0
//! 64  32 * n    section table: tag [u8; 4], flags u32 (bit 0: zstd), offset u64,
//!               stored length u64, raw (decompressed) length u64
//! ```
//! All integers are little-endian. Sections start at 16-byte-aligned offsets and hold rkyv
//! archives (zstd-compressed when flagged). Readers ignore tags they do not know.
//!
//! # The version rule
//! A reader reads the files of its own major version only. Within a major version:
//! - a minor version may add sections under new tags, which older readers skip;
//! - the sections of a baked file (`META`, `BASE`, `RTRE`, `TRNS`, `SLNK`, `TRPT`, `FLAT`,
//!   `TDRP`, `FLT2`, `TBNC`, `TCAM`) keep their layout for the whole major version, so every reader of the
//!   major version reads them from a file of any minor version;
//! - the layout of `TSHD`, which only the intermediate shard files of `bake --shard` carry
//!   (they are merged by the build that computed them), may change with a minor version. A
//!   reader reads a `TSHD` section only from the minor versions with the layout it knows
//!   ([`SHARD_LAYOUT_MINOR`] to its own [`VERSION_MINOR`]) and refuses it from any other,
//!   naming both versions.
//!
//! What each minor version added: 1.1 the transport operator (`TRNS`, `SLNK`); 1.2 the input
//! key in the header; 1.3 the optional `TRPT` section (error estimate, bounce choice, what was
//! left out); 1.4 the bounce policy in `TSHD`; 1.5 the optional `FLAT` section (the one-level
//! flat basis the viewer splats, `crate::flat_section`; a reader builds it from the basis and
//! links of a file without one), the optional `TDRP` section (the light the refinement of T
//! dropped) and the per-row sums behind it in `TSHD` (its current layout); 1.6 the `FLT2`
//! section, which replaces `FLAT` in the files it writes: the flat basis by a rule with one
//! more parameter (`finer_cover`: coarser points left out where finer ones cover them), so a
//! 1.5 reader skips it and builds the flat basis by its own rule; 1.7 the optional `TBNC` section
//! (how the coarsest receivers' later bounces were traced as paths) and those paths' rows in
//! `TSHD` (`level0_paths` and the owned rows); 1.8 the optional `TCAM` section (the bake's
//! check of its indirect light at the scene's camera) and, in `TSHD` (its current layout), the
//! representative emission sampled near the light as the viewer samples it (the same fields;
//! a 1.7 shard's emission is the point samples, so 1.7 shards are refused); 1.9 the optional
//! `CLIP` section (the supports' clip planes, read with the basis). From 1.4 the bake
//! stores each level's points in Morton order; readers do not rely on it.

use std::ops::Deref;
use std::path::Path;

use rkyv::util::AlignedVec;
use std::io::{Seek, SeekFrom, Write};

use xxhash_rust::xxh3::{xxh3_64, Xxh3};

use crate::error::FormatError;

pub const MAGIC: [u8; 8] = *b"\x89MLTBK\r\n";
pub const VERSION_MAJOR: u16 = 1;
/// The minor version this build writes (the module docs list what each one added).
pub const VERSION_MINOR: u16 = 9;
/// The first minor version with the `TSHD` layout this build reads.
pub const SHARD_LAYOUT_MINOR: u16 = 8;
pub const FIXED_HEADER: usize = 64;
pub const ENTRY_SIZE: usize = 32;
pub const ALIGN: usize = 16;
const FLAG_ZSTD: u32 = 1;
/// A decompressed section may be at most this many times its stored size (zstd's best ratio
/// is far below); guards against a forged length asking for an absurd allocation.
const MAX_EXPANSION: u64 = 1 << 12;

/// One entry of the section table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SectionEntry {
    pub tag: [u8; 4],
    pub compressed: bool,
    pub offset: u64,
    pub stored_len: u64,
    pub raw_len: u64,
}

impl SectionEntry {
    pub fn tag_str(&self) -> String {
        String::from_utf8_lossy(&self.tag).into_owned()
    }
}

/// A section to write.
pub struct SectionIn<'a> {
    pub tag: [u8; 4],
    pub bytes: &'a [u8],
    pub compress: bool,
}

fn align_up(x: usize) -> usize {
    x.div_ceil(ALIGN) * ALIGN
}

/// Serialises sections into a complete file image with `input_key` in the header.
/// Deterministic: the same sections give the same bytes (zstd at a fixed level,
/// single-threaded). The bytes are those [`Encoder`] writes.
pub fn encode(sections: &[SectionIn<'_>], input_key: u64) -> Result<Vec<u8>, FormatError> {
    let mut out = std::io::Cursor::new(Vec::new());
    let mut enc = Encoder::new(&mut out, sections.len(), input_key).map_err(write_err)?;
    for s in sections {
        enc.add(s).map_err(write_err)?;
    }
    enc.finish().map_err(write_err)?;
    Ok(out.into_inner())
}

fn write_err(e: std::io::Error) -> FormatError {
    FormatError::Serialize {
        tag: "file".into(),
        detail: e.to_string(),
    }
}

/// Writes a file image section by section to a seekable writer, so that a section's bytes need
/// not outlive its [`Encoder::add`] and the whole image is never held in memory: the header's
/// place is filled with zeros first, the payload's checksum is accumulated as the sections
/// pass, and [`Encoder::finish`] writes the header over its place. The bytes are those of
/// [`encode`] for the same sections in the same order.
pub struct Encoder<W: Write + Seek> {
    w: W,
    sections: usize,
    input_key: u64,
    header_len: usize,
    /// Bytes written so far, header's place included.
    len: usize,
    entries: Vec<SectionEntry>,
    payload: Xxh3,
}

impl<W: Write + Seek> Encoder<W> {
    /// Starts an image of `sections` sections at the writer's start.
    pub fn new(mut w: W, sections: usize, input_key: u64) -> std::io::Result<Encoder<W>> {
        let header_len = align_up(FIXED_HEADER + ENTRY_SIZE * sections);
        w.seek(SeekFrom::Start(0))?;
        w.write_all(&vec![0u8; header_len])?;
        Ok(Encoder {
            w,
            sections,
            input_key,
            header_len,
            len: header_len,
            entries: Vec::with_capacity(sections),
            payload: Xxh3::new(),
        })
    }

    /// Appends one section (compressed when it asks), padded to the alignment. An error
    /// (the writer's, the compressor's, or more sections than announced) names the section.
    pub fn add(&mut self, s: &SectionIn<'_>) -> std::io::Result<()> {
        let tag = String::from_utf8_lossy(&s.tag).into_owned();
        let err = |e: &dyn std::fmt::Display| std::io::Error::other(format!("section {tag}: {e}"));
        if self.entries.len() == self.sections {
            let e = format!("more than the {} sections announced", self.sections);
            return Err(err(&e));
        }
        let stored: std::borrow::Cow<[u8]> = if s.compress {
            zstd::bulk::compress(s.bytes, 9)
                .map_err(|e| err(&e))?
                .into()
        } else {
            s.bytes.into()
        };
        let offset = self.len;
        let pad = align_up(offset + stored.len()) - offset - stored.len();
        for part in [&stored[..], &[0u8; ALIGN][..pad]] {
            self.w.write_all(part).map_err(|e| err(&e))?;
            self.payload.update(part);
        }
        self.len += stored.len() + pad;
        self.entries.push(SectionEntry {
            tag: s.tag,
            compressed: s.compress,
            offset: offset as u64,
            stored_len: stored.len() as u64,
            raw_len: s.bytes.len() as u64,
        });
        Ok(())
    }

    /// Writes the header over its place and returns the writer and the image's length. Fails
    /// when fewer sections were added than announced.
    pub fn finish(mut self) -> std::io::Result<(W, u64)> {
        if self.entries.len() != self.sections {
            return Err(std::io::Error::other(format!(
                "{} of the {} sections announced were added",
                self.entries.len(),
                self.sections
            )));
        }
        let mut h = vec![0u8; self.header_len];
        h[0..8].copy_from_slice(&MAGIC);
        h[8..10].copy_from_slice(&VERSION_MAJOR.to_le_bytes());
        h[10..12].copy_from_slice(&VERSION_MINOR.to_le_bytes());
        h[16..20].copy_from_slice(&(self.header_len as u32).to_le_bytes());
        h[20..24].copy_from_slice(&(self.sections as u32).to_le_bytes());
        h[24..32].copy_from_slice(&(self.len as u64).to_le_bytes());
        h[48..56].copy_from_slice(&self.input_key.to_le_bytes());
        for (i, e) in self.entries.iter().enumerate() {
            let o = FIXED_HEADER + i * ENTRY_SIZE;
            h[o..o + 4].copy_from_slice(&e.tag);
            let flags = if e.compressed { FLAG_ZSTD } else { 0 };
            h[o + 4..o + 8].copy_from_slice(&flags.to_le_bytes());
            h[o + 8..o + 16].copy_from_slice(&e.offset.to_le_bytes());
            h[o + 16..o + 24].copy_from_slice(&e.stored_len.to_le_bytes());
            h[o + 24..o + 32].copy_from_slice(&e.raw_len.to_le_bytes());
        }
        // The checksums as `reseal` writes them: the payload's, then the header's with its
        // own field zeroed.
        h[32..40].copy_from_slice(&self.payload.digest().to_le_bytes());
        let header_hash = xxh3_64(&h);
        h[40..48].copy_from_slice(&header_hash.to_le_bytes());
        self.w.seek(SeekFrom::Start(0))?;
        self.w.write_all(&h)?;
        self.w.seek(SeekFrom::Start(self.len as u64))?;
        Ok((self.w, self.len as u64))
    }
}

/// Writes both checksums of a file image from its contents: the payload's (bytes
/// `header_len..`) and the header's (with its own field zeroed). For `encode`, and for tools and
/// tests that patch an image. Returns false, changing nothing, when the image is shorter than
/// the fixed header or its header-length field does not fit the image.
pub fn reseal(bytes: &mut [u8]) -> bool {
    if bytes.len() < FIXED_HEADER {
        return false;
    }
    let header_len = u32_at(bytes, 16) as usize;
    if header_len < FIXED_HEADER || header_len > bytes.len() {
        return false;
    }
    let payload_hash = xxh3_64(&bytes[header_len..]);
    bytes[32..40].copy_from_slice(&payload_hash.to_le_bytes());
    bytes[40..48].fill(0);
    let header_hash = xxh3_64(&bytes[..header_len]);
    bytes[40..48].copy_from_slice(&header_hash.to_le_bytes());
    true
}

fn u16_at(b: &[u8], o: usize) -> u16 {
    u16::from_le_bytes([b[o], b[o + 1]])
}
fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}
fn u64_at(b: &[u8], o: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[o..o + 8]);
    u64::from_le_bytes(a)
}

/// The parsed header of a file image.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Header {
    pub major: u16,
    pub minor: u16,
    pub header_len: usize,
    pub file_len: u64,
    pub payload_hash: u64,
    /// The bake's input key (0 when unknown).
    pub input_key: u64,
    pub sections: Vec<SectionEntry>,
}

/// Checks magic, version, lengths, both checksums and the section table of a file image.
pub fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header, FormatError> {
    let truncated = |detail: String| FormatError::Truncated {
        path: path.to_path_buf(),
        detail,
    };
    if bytes.len() < 8 || bytes[..8] != MAGIC {
        if bytes.len() < 8 && MAGIC.starts_with(bytes) {
            return Err(truncated(format!("only {} bytes", bytes.len())));
        }
        return Err(FormatError::BadMagic {
            path: path.to_path_buf(),
        });
    }
    if bytes.len() < FIXED_HEADER {
        return Err(truncated(format!(
            "{} bytes, shorter than the {FIXED_HEADER}-byte header",
            bytes.len()
        )));
    }
    let major = u16_at(bytes, 8);
    let minor = u16_at(bytes, 10);
    if major != VERSION_MAJOR {
        return Err(FormatError::WrongVersion {
            path: path.to_path_buf(),
            major,
            minor,
            supported: VERSION_MAJOR,
        });
    }
    let header_len = u32_at(bytes, 16) as usize;
    let count = u32_at(bytes, 20) as usize;
    let file_len = u64_at(bytes, 24);
    if file_len != bytes.len() as u64 {
        return Err(truncated(format!(
            "header says {file_len} bytes, the file has {}",
            bytes.len()
        )));
    }
    if header_len < FIXED_HEADER
        || !header_len.is_multiple_of(ALIGN)
        || header_len > bytes.len()
        || count > (header_len - FIXED_HEADER) / ENTRY_SIZE
    {
        return Err(truncated(format!(
            "bad header length {header_len} for {count} sections"
        )));
    }
    let mut header = bytes[..header_len].to_vec();
    header[40..48].fill(0);
    let stored = u64_at(bytes, 40);
    let computed = xxh3_64(&header);
    if stored != computed {
        return Err(FormatError::Checksum {
            path: path.to_path_buf(),
            what: "header",
            stored,
            computed,
        });
    }
    let payload_hash = u64_at(bytes, 32);
    let computed = xxh3_64(&bytes[header_len..]);
    if payload_hash != computed {
        return Err(FormatError::Checksum {
            path: path.to_path_buf(),
            what: "payload",
            stored: payload_hash,
            computed,
        });
    }
    let mut sections = Vec::with_capacity(count);
    for i in 0..count {
        let o = FIXED_HEADER + i * ENTRY_SIZE;
        let mut tag = [0u8; 4];
        tag.copy_from_slice(&bytes[o..o + 4]);
        let flags = u32_at(bytes, o + 4);
        let e = SectionEntry {
            tag,
            compressed: flags & FLAG_ZSTD != 0,
            offset: u64_at(bytes, o + 8),
            stored_len: u64_at(bytes, o + 16),
            raw_len: u64_at(bytes, o + 24),
        };
        let end = e.offset.checked_add(e.stored_len);
        if e.offset < header_len as u64
            || !e.offset.is_multiple_of(ALIGN as u64)
            || end.is_none_or(|end| end > file_len)
            || (!e.compressed && e.raw_len != e.stored_len)
            || (e.compressed && e.raw_len > e.stored_len.saturating_mul(MAX_EXPANSION))
        {
            return Err(truncated(format!(
                "section '{}' lies outside the file or has inconsistent lengths",
                e.tag_str()
            )));
        }
        sections.push(e);
    }
    Ok(Header {
        major,
        minor,
        header_len,
        file_len,
        payload_hash,
        input_key: u64_at(bytes, 48),
        sections,
    })
}

/// A section's bytes, 16-byte aligned: borrowed from the mapped file, or decompressed.
pub enum SectionBytes<'a> {
    Borrowed(&'a [u8]),
    Owned(AlignedVec<ALIGN>),
}

impl Deref for SectionBytes<'_> {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            SectionBytes::Borrowed(b) => b,
            SectionBytes::Owned(v) => v.as_slice(),
        }
    }
}

/// The bytes of section `e` of a validated image `bytes` (whose start is 16-byte aligned).
pub fn section_bytes<'a>(
    path: &Path,
    bytes: &'a [u8],
    e: &SectionEntry,
) -> Result<SectionBytes<'a>, FormatError> {
    let stored = &bytes[e.offset as usize..(e.offset + e.stored_len) as usize];
    if !e.compressed {
        return Ok(SectionBytes::Borrowed(stored));
    }
    let raw = zstd::bulk::decompress(stored, e.raw_len as usize).map_err(|err| {
        FormatError::BadSection {
            path: path.to_path_buf(),
            tag: e.tag_str(),
            detail: format!("zstd: {err}"),
        }
    })?;
    if raw.len() as u64 != e.raw_len {
        return Err(FormatError::BadSection {
            path: path.to_path_buf(),
            tag: e.tag_str(),
            detail: format!(
                "decompressed to {} bytes, expected {}",
                raw.len(),
                e.raw_len
            ),
        });
    }
    let mut v = AlignedVec::<ALIGN>::with_capacity(raw.len());
    v.extend_from_slice(&raw);
    Ok(SectionBytes::Owned(v))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(compress: bool) -> Vec<u8> {
        let a = vec![7u8; 1000];
        let b = b"hello".to_vec();
        let sections = [
            SectionIn {
                tag: *b"AAAA",
                bytes: &a,
                compress,
            },
            SectionIn {
                tag: *b"BBBB",
                bytes: &b,
                compress: false,
            },
        ];
        encode(&sections, 0x1234).unwrap()
    }

    #[test]
    fn the_encoder_writes_the_sealed_image_byte_for_byte() {
        // The image laid out by hand: the header's place, each section padded to the
        // alignment, the header's fields, then both checksums by `reseal`.
        let a: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 251) as u8).collect();
        let b = b"hello".to_vec();
        let empty: Vec<u8> = Vec::new();
        let parts = [(*b"AAAA", &a), (*b"BBBB", &b), (*b"CCCC", &empty)];
        let header_len = align_up(FIXED_HEADER + ENTRY_SIZE * parts.len());
        let mut want = vec![0u8; header_len];
        let mut entries = Vec::new();
        for (tag, bytes) in &parts {
            entries.push((*tag, want.len() as u64, bytes.len() as u64));
            want.extend_from_slice(bytes);
            want.resize(align_up(want.len()), 0);
        }
        want[0..8].copy_from_slice(&MAGIC);
        want[8..10].copy_from_slice(&VERSION_MAJOR.to_le_bytes());
        want[10..12].copy_from_slice(&VERSION_MINOR.to_le_bytes());
        want[16..20].copy_from_slice(&(header_len as u32).to_le_bytes());
        want[20..24].copy_from_slice(&(parts.len() as u32).to_le_bytes());
        let file_len = want.len() as u64;
        want[24..32].copy_from_slice(&file_len.to_le_bytes());
        want[48..56].copy_from_slice(&0x5678u64.to_le_bytes());
        for (i, (tag, offset, len)) in entries.iter().enumerate() {
            let o = FIXED_HEADER + i * ENTRY_SIZE;
            want[o..o + 4].copy_from_slice(tag);
            want[o + 8..o + 16].copy_from_slice(&offset.to_le_bytes());
            want[o + 16..o + 24].copy_from_slice(&len.to_le_bytes());
            want[o + 24..o + 32].copy_from_slice(&len.to_le_bytes());
        }
        assert!(reseal(&mut want));
        let sections: Vec<SectionIn> = parts
            .iter()
            .map(|(tag, bytes)| SectionIn {
                tag: *tag,
                bytes,
                compress: false,
            })
            .collect();
        assert_eq!(encode(&sections, 0x5678).unwrap(), want);
        // Into a writer that holds other bytes: the image is written from its start, over them.
        let mut enc = Encoder::new(std::io::Cursor::new(vec![9u8; 4000]), 3, 0x5678).unwrap();
        for s in &sections {
            enc.add(s).unwrap();
        }
        let (w, len) = enc.finish().unwrap();
        assert_eq!(len, file_len);
        assert_eq!(&w.into_inner()[..want.len()], &want[..]);
        // Not the sections announced: refused.
        let mut enc = Encoder::new(std::io::Cursor::new(Vec::new()), 2, 0).unwrap();
        enc.add(&sections[0]).unwrap();
        assert!(enc.finish().is_err());
        let mut enc = Encoder::new(std::io::Cursor::new(Vec::new()), 1, 0).unwrap();
        enc.add(&sections[0]).unwrap();
        let e = enc.add(&sections[1]).unwrap_err().to_string();
        assert!(e.contains("BBBB") && e.contains("more than the 1"), "{e}");
    }

    #[test]
    fn round_trip_and_alignment() {
        for compress in [false, true] {
            let img = image(compress);
            let p = Path::new("t.mlt");
            let h = parse_header(p, &img).unwrap();
            assert_eq!(h.sections.len(), 2);
            assert_eq!(h.input_key, 0x1234);
            for e in &h.sections {
                assert_eq!(e.offset % 16, 0);
            }
            let mut aligned = AlignedVec::<16>::new();
            aligned.extend_from_slice(&img);
            let a = section_bytes(p, &aligned, &h.sections[0]).unwrap();
            assert_eq!(&a[..], &vec![7u8; 1000][..]);
            let b = section_bytes(p, &aligned, &h.sections[1]).unwrap();
            assert_eq!(&b[..], b"hello");
        }
        assert!(image(true).len() < image(false).len());
        assert_eq!(image(true), image(true));
    }

    #[test]
    fn every_truncation_and_every_flipped_byte_is_rejected() {
        let img = image(false);
        let p = Path::new("t.mlt");
        for len in 0..img.len() {
            assert!(parse_header(p, &img[..len]).is_err(), "truncated to {len}");
        }
        for i in 0..img.len() {
            let mut bad = img.clone();
            bad[i] ^= 0x10;
            assert!(parse_header(p, &bad).is_err(), "flipped byte {i}");
        }
    }

    #[test]
    fn wrong_version_and_magic_are_named() {
        let p = Path::new("t.mlt");
        let mut img = image(false);
        img[8] = 2;
        let e = parse_header(p, &img).unwrap_err();
        assert!(
            matches!(e, FormatError::WrongVersion { major: 2, .. }),
            "{e}"
        );
        assert!(e.to_string().contains("t.mlt"));
        let e = parse_header(p, b"# not a baked file, just text\n").unwrap_err();
        assert!(matches!(e, FormatError::BadMagic { .. }));
    }
}
