//! Baked files: writing them atomically, memory-mapping and validating them, and reading
//! their sections.

use std::fs;
use std::io::Write;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};

use memmap2::Mmap;
use rkyv::rancor;
use rkyv::util::AlignedVec;
use serde::Serialize;

use crate::basis::Basis;
use crate::container::{
    self, Header, SectionBytes, SectionIn, ALIGN, SHARD_LAYOUT_MINOR, VERSION_MAJOR, VERSION_MINOR,
};
use crate::error::FormatError;
use crate::flat_section::{
    ArchivedFlatSection, ArchivedFlatSection1_5, FlatRule, FlatSection, StoredFlat,
};
use crate::links::{ArchivedLinks, Links};
use crate::meta::{
    BounceMethod, CameraBlocks, CameraCheck, Meta, RefinementDrop, TransportMeta, TransportReport,
};
use crate::rtree::RTree;
use crate::shard::ShardSection;
use crate::shepard::IndexedBasis;
use crate::support_clip::SupportClip;

/// Section tags of format 1.0.
pub const TAG_META: [u8; 4] = *b"META";
pub const TAG_BASIS: [u8; 4] = *b"BASE";
pub const TAG_RTREES: [u8; 4] = *b"RTRE";
/// Added in format 1.1: the transport operator S and how it was made.
pub const TAG_TRANSPORT: [u8; 4] = *b"TRNS";
pub const TAG_LINKS: [u8; 4] = *b"SLNK";
/// Added in format 1.3: the bake's error estimate, bounce choice and what it left out
/// ([`TransportReport`]); optional, so 1.1 and 1.2 files still read.
pub const TAG_REPORT: [u8; 4] = *b"TRPT";
/// A shard's share of T (shard files only).
pub const TAG_SHARD: [u8; 4] = *b"TSHD";
/// Added in format 1.5: the one-level flat basis of that format's rule
/// ([`crate::flat_section::FlatSection1_5`]); optional, so older files still read (a viewer
/// then builds the flat basis when it opens them). Since 1.6 bakes write `FLT2` instead, and
/// readers take only the rule from a `FLAT` section.
pub const TAG_FLAT: [u8; 4] = *b"FLAT";
/// Added in format 1.6, written instead of `FLAT`: the flat basis by a rule with
/// `finer_cover` ([`FlatSection`]). A file with only a `FLAT` section
/// ([`crate::flat_section::FlatSection1_5`]) has it read for its rule, an older one than this
/// build's.
pub const TAG_FLAT2: [u8; 4] = *b"FLT2";
/// Added in format 1.5: the light the refinement of T dropped ([`RefinementDrop`]);
/// optional, so older files still read.
pub const TAG_DROP: [u8; 4] = *b"TDRP";
/// Added in format 1.7: how the level-0 rows' later bounces were computed when the bake
/// traced them as paths ([`BounceMethod`]); optional, absent for the series' chain.
pub const TAG_BOUNCES: [u8; 4] = *b"TBNC";
/// Added in format 1.8: the bake's check of its indirect light at the scene's camera
/// ([`CameraCheck`]); optional.
pub const TAG_CAMERA_CHECK: [u8; 4] = *b"TCAM";
/// Added in format 1.9: the basis functions' supports clipped at occluders
/// ([`crate::support_clip::SupportClip`]); optional, written when some point is clipped, so
/// older files read with unclipped supports.
pub const TAG_CLIP: [u8; 4] = *b"CLIP";
/// Added in format 1.9: the camera check by blocks ([`CameraBlocks`]); optional.
pub const TAG_CAMERA_BLOCKS: [u8; 4] = *b"TCBK";

/// The minor versions (of [`VERSION_MAJOR`]) from which this build reads the section `tag`:
/// any for the sections of a baked file, whose layout is fixed within the major version; for
/// `TSHD`, whose layout a minor version may change, [`SHARD_LAYOUT_MINOR`] to
/// [`VERSION_MINOR`] (the version rule in [`crate::container`]).
pub fn readable_minors(tag: [u8; 4]) -> RangeInclusive<u16> {
    if tag == TAG_SHARD {
        SHARD_LAYOUT_MINOR..=VERSION_MINOR
    } else {
        0..=u16::MAX
    }
}

/// The R-trees of all levels, archived together.
#[derive(Clone, Debug, Default, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct RTrees {
    pub levels: Vec<RTree>,
}

/// What a bake produces and a file holds.
#[derive(Clone, Debug, PartialEq)]
pub struct BakeContents {
    pub meta: Meta,
    pub basis: IndexedBasis,
    /// The transport operator, when the bake computed one.
    pub transport: Option<Transport>,
    /// xxh3-64 of everything the result depends on (scene bytes, parameters, tool version);
    /// stored in the header so that build systems can tell an up-to-date output cheaply.
    pub input_key: u64,
    /// In a shard file: the shard's share of T.
    pub shard: Option<ShardSection>,
    /// The flat basis for the transport's links (`FLT2`, format 1.6; `None` in older files,
    /// whose 1.5 `FLAT` section is by an older rule, in shard files and in files without
    /// transport).
    pub flat: Option<FlatSection>,
}

/// The direct-to-indirect operator S with its parameters and statistics.
#[derive(Clone, Debug, PartialEq)]
pub struct Transport {
    pub meta: TransportMeta,
    pub links: Links,
    /// The `TRPT` section; `None` in files written before format 1.3.
    pub report: Option<TransportReport>,
    /// The `TDRP` section; `None` in files written before format 1.5.
    pub drop: Option<RefinementDrop>,
    /// The `TBNC` section; `None` where the series chained the bounces (and before 1.7).
    pub bounces: Option<BounceMethod>,
    /// The `TCAM` section; `None` before 1.8 and in merges made without the scene.
    pub camera_check: Option<CameraCheck>,
    /// The `TCBK` section; `None` before 1.9 and where `TCAM` is absent.
    pub camera_blocks: Option<CameraBlocks>,
}

/// How to write.
#[derive(Clone, Copy, Debug, Default)]
pub struct WriteOptions {
    /// zstd-compress every section (smaller files; readers then decompress instead of
    /// mapping the sections in place).
    pub compress: bool,
}

fn ser_err(tag: [u8; 4]) -> impl Fn(rancor::Error) -> FormatError {
    move |e| FormatError::Serialize {
        tag: String::from_utf8_lossy(&tag).into_owned(),
        detail: e.to_string(),
    }
}

/// A section's tag and how to serialise it.
type LazySection<'c> = (
    [u8; 4],
    Box<dyn Fn() -> Result<AlignedVec, FormatError> + 'c>,
);

/// The sections of `contents`, in file order, each serialised only when asked.
fn sections(contents: &BakeContents) -> Vec<LazySection<'_>> {
    fn lazy<'c, T>(tag: [u8; 4], value: &'c T) -> LazySection<'c>
    where
        T: for<'a> rkyv::Serialize<
            rkyv::api::high::HighSerializer<
                AlignedVec,
                rkyv::ser::allocator::ArenaHandle<'a>,
                rancor::Error,
            >,
        >,
    {
        (
            tag,
            Box::new(move || rkyv::to_bytes::<rancor::Error>(value).map_err(ser_err(tag))),
        )
    }
    let mut out: Vec<LazySection<'_>> = vec![
        lazy(TAG_META, &contents.meta),
        lazy(TAG_BASIS, &contents.basis.basis),
        (
            TAG_RTREES,
            Box::new(|| {
                let trees = RTrees {
                    levels: contents.basis.trees.clone(),
                };
                rkyv::to_bytes::<rancor::Error>(&trees).map_err(ser_err(TAG_RTREES))
            }),
        ),
    ];
    if !contents.basis.clip.is_empty() {
        out.push(lazy(TAG_CLIP, &contents.basis.clip));
    }
    if let Some(t) = &contents.transport {
        out.push(lazy(TAG_TRANSPORT, &t.meta));
        out.push(lazy(TAG_LINKS, &t.links));
        if let Some(r) = &t.report {
            out.push(lazy(TAG_REPORT, r));
        }
        if let Some(d) = &t.drop {
            out.push(lazy(TAG_DROP, d));
        }
        if let Some(b) = &t.bounces {
            out.push(lazy(TAG_BOUNCES, b));
        }
        if let Some(c) = &t.camera_check {
            out.push(lazy(TAG_CAMERA_CHECK, c));
        }
        if let Some(c) = &t.camera_blocks {
            out.push(lazy(TAG_CAMERA_BLOCKS, c));
        }
    }
    if let Some(sh) = &contents.shard {
        out.push(lazy(TAG_SHARD, sh));
    }
    if let Some(f) = &contents.flat {
        out.push(lazy(TAG_FLAT2, f));
    }
    out
}

/// Writes the image of `contents` to `w` section by section ([`container::Encoder`]): one
/// section's serialised bytes are held at a time, never the whole image. Returns the length;
/// `io` turns the writer's errors into the caller's.
fn encode_to<W: std::io::Write + std::io::Seek>(
    contents: &BakeContents,
    opts: WriteOptions,
    w: W,
    io: impl Fn(std::io::Error) -> FormatError,
) -> Result<(W, u64), FormatError> {
    let lazy = sections(contents);
    let mut enc = container::Encoder::new(w, lazy.len(), contents.input_key).map_err(&io)?;
    for (tag, serialise) in &lazy {
        let bytes = serialise()?;
        enc.add(&SectionIn {
            tag: *tag,
            bytes: &bytes,
            compress: opts.compress,
        })
        .map_err(&io)?;
    }
    enc.finish().map_err(io)
}

/// The complete file image for `contents`; deterministic.
pub fn encode(contents: &BakeContents, opts: WriteOptions) -> Result<Vec<u8>, FormatError> {
    let io = |e: std::io::Error| FormatError::Serialize {
        tag: "file".into(),
        detail: e.to_string(),
    };
    let (cursor, _) = encode_to(contents, opts, std::io::Cursor::new(Vec::new()), io)?;
    Ok(cursor.into_inner())
}

/// Bytes each section of `contents` takes uncompressed, by tag (for statistics).
pub fn section_sizes(contents: &BakeContents) -> Result<Vec<([u8; 4], u64)>, FormatError> {
    let bytes = encode(contents, WriteOptions { compress: false })?;
    let header = container::parse_header(Path::new("(in memory)"), &bytes)?;
    Ok(header
        .sections
        .iter()
        .map(|e| (e.tag, e.stored_len))
        .collect())
}

/// Writes `bytes` to `path` through a temporary file in the same directory that is renamed
/// into place, so that an existing file is never left half-written: readers see the old file
/// or the new one.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), FormatError> {
    write_atomic_with(path, |f| {
        f.write_all(bytes).map_err(|source| io_err(path, source))
    })
}

fn io_err(path: &Path, error: std::io::Error) -> FormatError {
    FormatError::Io {
        path: path.to_path_buf(),
        error,
    }
}

/// [`write_atomic`] with the contents written by `fill` into the temporary file; an error
/// from `fill` removes the temporary file and leaves `path` as it was.
fn write_atomic_with<T>(
    path: &Path,
    fill: impl FnOnce(&mut fs::File) -> Result<T, FormatError>,
) -> Result<T, FormatError> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut f = fs::File::create(&tmp).map_err(|e| io_err(path, e))?;
        let value = fill(&mut f)?;
        f.sync_all().map_err(|e| io_err(path, e))?;
        drop(f);
        fs::rename(&tmp, path).map_err(|e| io_err(path, e))?;
        Ok(value)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Encodes and writes `contents` atomically, a section at a time; returns the file size.
pub fn write(path: &Path, contents: &BakeContents, opts: WriteOptions) -> Result<u64, FormatError> {
    write_atomic_with(path, |f| {
        let w = std::io::BufWriter::new(f);
        // A failed write (a full disk) names the file.
        let (mut w, len) = encode_to(contents, opts, w, |e| io_err(path, e))?;
        w.flush().map_err(|e| io_err(path, e))?;
        Ok(len)
    })
}

enum Storage {
    Mapped(Mmap),
    Owned(AlignedVec<ALIGN>),
}

/// An opened, validated baked file (memory-mapped when opened from disk).
pub struct BakedFile {
    path: PathBuf,
    storage: Storage,
    header: Header,
}

impl BakedFile {
    /// Memory-maps `path` and validates magic, version, length, checksums and the section
    /// table. Section contents are validated when read.
    pub fn open(path: &Path) -> Result<BakedFile, FormatError> {
        let file = fs::File::open(path).map_err(|error| FormatError::Io {
            path: path.to_path_buf(),
            error,
        })?;
        // SAFETY: the mapping is read-only and private to this process. Its contents can only
        // change under us if another process writes to this very file while it is mapped;
        // our writers never do that (they write a temporary file and rename it over the old
        // one, which leaves existing mappings of the old inode intact). Every byte we read is
        // bounds-checked against the header and checksummed before use, so a file rewritten
        // in place between open and read gives an error, not undefined behaviour in our code.
        // A file truncated in place is different: reading a mapped page past its new end
        // raises SIGBUS, which ends the process (no writer here truncates in place).
        let map = unsafe { Mmap::map(&file) }.map_err(|error| FormatError::Io {
            path: path.to_path_buf(),
            error,
        })?;
        let header = container::parse_header(path, &map)?;
        Ok(BakedFile {
            path: path.to_path_buf(),
            storage: Storage::Mapped(map),
            header,
        })
    }

    /// Validates an in-memory image (copied into aligned storage); `path` names it in errors.
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<BakedFile, FormatError> {
        let mut v = AlignedVec::<ALIGN>::with_capacity(bytes.len());
        v.extend_from_slice(bytes);
        let header = container::parse_header(path, &v)?;
        Ok(BakedFile {
            path: path.to_path_buf(),
            storage: Storage::Owned(v),
            header,
        })
    }

    fn bytes(&self) -> &[u8] {
        match &self.storage {
            Storage::Mapped(m) => m,
            Storage::Owned(v) => v.as_slice(),
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    pub fn file_len(&self) -> u64 {
        self.header.file_len
    }

    fn has_section(&self, tag: [u8; 4]) -> bool {
        self.entry(tag).is_some()
    }

    /// The section table's entry of `tag`, if the file has that section.
    fn entry(&self, tag: [u8; 4]) -> Option<&container::SectionEntry> {
        self.header.sections.iter().find(|e| e.tag == tag)
    }

    /// [`BakedFile::section`] where the section may be absent: `None` then.
    fn optional_section<T>(&self, tag: [u8; 4]) -> Result<Option<T>, FormatError>
    where
        T: rkyv::Archive,
        T::Archived: for<'a> rkyv::bytecheck::CheckBytes<rkyv::api::high::HighValidator<'a, rancor::Error>>
            + rkyv::Deserialize<T, rkyv::api::high::HighDeserializer<rancor::Error>>,
    {
        if !self.has_section(tag) {
            return Ok(None);
        }
        self.section::<T>(tag).map(Some)
    }

    fn section<T>(&self, tag: [u8; 4]) -> Result<T, FormatError>
    where
        T: rkyv::Archive,
        T::Archived: for<'a> rkyv::bytecheck::CheckBytes<rkyv::api::high::HighValidator<'a, rancor::Error>>
            + rkyv::Deserialize<T, rkyv::api::high::HighDeserializer<rancor::Error>>,
    {
        let tag_str = String::from_utf8_lossy(&tag).into_owned();
        self.check_layout(tag, &tag_str)?;
        let entry = self.entry(tag).ok_or_else(|| FormatError::MissingSection {
            path: self.path.clone(),
            tag: tag_str.clone(),
        })?;
        let bytes = container::section_bytes(&self.path, self.bytes(), entry)?;
        let bad = |detail: String| FormatError::BadSection {
            path: self.path.clone(),
            tag: tag_str.clone(),
            detail,
        };
        let archived =
            rkyv::access::<T::Archived, rancor::Error>(&bytes).map_err(|e| bad(e.to_string()))?;
        rkyv::deserialize::<T, rancor::Error>(archived).map_err(|e| bad(e.to_string()))
    }

    /// Refuses the section `tag` when this file's minor version may hold it in a layout this
    /// build does not read ([`readable_minors`]).
    fn check_layout(&self, tag: [u8; 4], tag_str: &str) -> Result<(), FormatError> {
        let minors = readable_minors(tag);
        let minor = self.header.minor;
        if minors.contains(&minor) {
            return Ok(());
        }
        let (first, last) = (*minors.start(), *minors.end());
        let detail = if minor < first {
            format!(
                "written by format {VERSION_MAJOR}.{minor}, whose layout of this section this \
                 build does not read (it reads {VERSION_MAJOR}.{first} to {VERSION_MAJOR}.{last}); \
                 compute the file again"
            )
        } else {
            format!(
                "written by format {VERSION_MAJOR}.{minor}, whose layout of this section may \
                 differ from the one this build reads ({VERSION_MAJOR}.{first} to \
                 {VERSION_MAJOR}.{last}); read it with the build that wrote it"
            )
        };
        Err(FormatError::BadSection {
            path: self.path.clone(),
            tag: tag_str.to_string(),
            detail,
        })
    }

    /// The `META` section.
    pub fn meta(&self) -> Result<Meta, FormatError> {
        self.section::<Meta>(TAG_META)
    }

    /// The basis and its R-trees, validated (structure, finiteness, tree shape and bounds),
    /// with its supports' clip planes where the file has them.
    pub fn basis(&self) -> Result<IndexedBasis, FormatError> {
        let basis = self.section::<Basis>(TAG_BASIS)?;
        let trees = self.section::<RTrees>(TAG_RTREES)?;
        let ib =
            IndexedBasis::from_parts(basis, trees.levels).map_err(|e| FormatError::BadSection {
                path: self.path.clone(),
                tag: "BASE".into(),
                detail: e.to_string(),
            })?;
        match self.optional_section::<SupportClip>(TAG_CLIP)? {
            None => Ok(ib),
            Some(clip) => ib.with_clip(clip).map_err(|e| FormatError::BadSection {
                path: self.path.clone(),
                tag: "CLIP".into(),
                detail: e.to_string(),
            }),
        }
    }

    /// The `TRNS` section, if the file has one.
    pub fn transport_meta(&self) -> Result<Option<TransportMeta>, FormatError> {
        self.optional_section::<TransportMeta>(TAG_TRANSPORT)
    }

    /// The `TRPT` section, if the file has one (format 1.3 and later, with transport).
    pub fn transport_report(&self) -> Result<Option<TransportReport>, FormatError> {
        self.optional_section::<TransportReport>(TAG_REPORT)
    }

    /// The `TDRP` section, if the file has one (format 1.5 and later, with transport).
    pub fn refinement_drop(&self) -> Result<Option<RefinementDrop>, FormatError> {
        self.optional_section::<RefinementDrop>(TAG_DROP)
    }

    /// The `TBNC` section, if the file has one (format 1.7 and later, with level-0 bounces
    /// traced as paths).
    pub fn bounce_method(&self) -> Result<Option<BounceMethod>, FormatError> {
        self.optional_section::<BounceMethod>(TAG_BOUNCES)
    }

    /// The `TCAM` section, if the file has one (format 1.8 and later, with transport).
    pub fn camera_check(&self) -> Result<Option<CameraCheck>, FormatError> {
        self.optional_section::<CameraCheck>(TAG_CAMERA_CHECK)
    }

    /// The `TCBK` section, if the file has one (format 1.9 and later, with `TCAM`).
    pub fn camera_blocks(&self) -> Result<Option<CameraBlocks>, FormatError> {
        self.optional_section::<CameraBlocks>(TAG_CAMERA_BLOCKS)
    }

    /// The `TSHD` section of a shard file, validated against the basis' size.
    pub fn shard(&self) -> Result<Option<ShardSection>, FormatError> {
        if !self.has_section(TAG_SHARD) {
            return Ok(None);
        }
        let s = self.section::<ShardSection>(TAG_SHARD)?;
        let b = self.section::<Basis>(TAG_BASIS)?;
        s.validate(b.len(), b.levels())
            .map_err(|detail| FormatError::BadSection {
                path: self.path.clone(),
                tag: "TSHD".into(),
                detail,
            })?;
        Ok(Some(s))
    }

    /// The bytes of the `SLNK` section, if present: borrowed from the mapping when stored
    /// uncompressed. Pass them to [`access_links`] for zero-copy, validated access.
    pub fn links_bytes(&self) -> Result<Option<SectionBytes<'_>>, FormatError> {
        match self.entry(TAG_LINKS) {
            None => Ok(None),
            Some(e) => container::section_bytes(&self.path, self.bytes(), e).map(Some),
        }
    }

    /// Reads everything (the links copied into owned memory).
    pub fn contents(&self) -> Result<BakeContents, FormatError> {
        let transport = match self.transport_meta()? {
            None => None,
            Some(meta) => {
                let links = self.section::<Links>(TAG_LINKS)?;
                links.validate().map_err(|e| self.bad_links(e))?;
                Some(Transport {
                    meta,
                    links,
                    report: self.transport_report()?,
                    drop: self.refinement_drop()?,
                    bounces: self.bounce_method()?,
                    camera_check: self.camera_check()?,
                    camera_blocks: self.camera_blocks()?,
                })
            }
        };
        Ok(BakeContents {
            meta: self.meta()?,
            basis: self.basis()?,
            transport,
            input_key: self.header.input_key,
            shard: self.shard()?,
            flat: self.flat_section()?,
        })
    }

    /// The `FLT2` section as stored (validated by rkyv only; [`BakedFile::flat_basis`] checks
    /// it against the basis and links), if the file has one.
    /// A file with only the format 1.5 section, built by an older rule, gives `None`.
    pub fn flat_section(&self) -> Result<Option<FlatSection>, FormatError> {
        if !self.has_section(TAG_FLAT2) {
            return Ok(None);
        }
        self.section::<FlatSection>(TAG_FLAT2).map(Some)
    }

    /// The flat basis stored in the `FLT2` section, read in place from the mapping and checked
    /// against this file's basis `hier` and the link flags `linked` of its links
    /// ([`crate::flat_section::linked_flags`]). A section that does not match them or is
    /// malformed is an error naming the file; one built by another rule than this build's is
    /// [`StoredFlat::OtherRule`] (build it instead).
    pub fn flat_basis(
        &self,
        hier: &IndexedBasis,
        linked: &[bool],
    ) -> Result<StoredFlat, FormatError> {
        let bad = |tag: [u8; 4], detail: String| FormatError::BadSection {
            path: self.path.clone(),
            tag: String::from_utf8_lossy(&tag).into_owned(),
            detail,
        };
        if let Some(entry) = self.entry(TAG_FLAT2) {
            let bytes = container::section_bytes(&self.path, self.bytes(), entry)?;
            let section = rkyv::access::<ArchivedFlatSection, rancor::Error>(&bytes)
                .map_err(|e| bad(TAG_FLAT2, e.to_string()))?;
            let rule = section.rule();
            if rule != FlatRule::current() {
                return Ok(StoredFlat::OtherRule(rule));
            }
            return section
                .flat_basis(hier, linked)
                .map(|f| StoredFlat::Stored(Box::new(f)))
                .map_err(|detail| bad(TAG_FLAT2, detail));
        }
        // Format 1.5's section, read for its rule only: always an older rule than this build's.
        let Some(entry) = self.entry(TAG_FLAT) else {
            return Ok(StoredFlat::Absent);
        };
        let bytes = container::section_bytes(&self.path, self.bytes(), entry)?;
        let old = rkyv::access::<ArchivedFlatSection1_5, rancor::Error>(&bytes)
            .map_err(|e| bad(TAG_FLAT, e.to_string()))?;
        Ok(StoredFlat::OtherRule(old.rule()))
    }

    fn bad_links(&self, e: FormatError) -> FormatError {
        FormatError::BadSection {
            path: self.path.clone(),
            tag: "SLNK".into(),
            detail: e.to_string(),
        }
    }

    /// Validated zero-copy access to links whose bytes came from [`BakedFile::links_bytes`].
    pub fn access_links<'b>(&self, bytes: &'b [u8]) -> Result<&'b ArchivedLinks, FormatError> {
        let links = rkyv::access::<ArchivedLinks, rancor::Error>(bytes).map_err(|e| {
            FormatError::BadSection {
                path: self.path.clone(),
                tag: "SLNK".into(),
                detail: e.to_string(),
            }
        })?;
        links.validate().map_err(|e| self.bad_links(e))?;
        Ok(links)
    }

    /// A summary for `bake info`.
    pub fn info(&self) -> Result<FileInfo, FormatError> {
        let meta = self.meta()?;
        let b = self.section::<Basis>(TAG_BASIS)?;
        let levels = (0..b.levels())
            .map(|l| LevelInfo {
                level: l as u32,
                points: b.level_range(l).len() as u64,
                disk_radius: b.disk_radii.get(l).copied().unwrap_or(0.0),
                support_radius: b
                    .level_range(l)
                    .next()
                    .and_then(|j| b.radii.get(j).copied())
                    .unwrap_or(0.0),
            })
            .collect();
        Ok(FileInfo {
            path: self.path.display().to_string(),
            format_version: format!("{}.{}", self.header.major, self.header.minor),
            input_key: format!("{:016x}", self.header.input_key),
            file_bytes: self.header.file_len,
            sections: self
                .header
                .sections
                .iter()
                .map(|e| SectionInfo {
                    tag: e.tag_str(),
                    offset: e.offset,
                    stored_bytes: e.stored_len,
                    raw_bytes: e.raw_len,
                    compressed: e.compressed,
                })
                .collect(),
            points: b.len() as u64,
            levels,
            meta,
            transport: self.transport_meta()?,
            report: self.transport_report()?,
            refinement_drop: self.refinement_drop()?,
            bounce_method: self.bounce_method()?,
            camera_check: self.camera_check()?,
            camera_blocks: self.camera_blocks()?,
        })
    }
}

/// `bake info` output.
#[derive(Clone, Debug, Serialize)]
pub struct FileInfo {
    pub path: String,
    pub format_version: String,
    pub input_key: String,
    pub file_bytes: u64,
    pub sections: Vec<SectionInfo>,
    pub points: u64,
    pub levels: Vec<LevelInfo>,
    pub meta: Meta,
    pub transport: Option<TransportMeta>,
    /// The `TRPT` section (format 1.3 and later).
    pub report: Option<TransportReport>,
    /// The `TDRP` section (format 1.5 and later).
    pub refinement_drop: Option<RefinementDrop>,
    /// The `TBNC` section (format 1.7 and later, level-0 bounces traced as paths).
    pub bounce_method: Option<BounceMethod>,
    /// The `TCAM` section (format 1.8 and later).
    pub camera_check: Option<CameraCheck>,
    /// The `TCBK` section (format 1.9 and later).
    pub camera_blocks: Option<CameraBlocks>,
}

#[derive(Clone, Debug, Serialize)]
pub struct SectionInfo {
    pub tag: String,
    pub offset: u64,
    pub stored_bytes: u64,
    pub raw_bytes: u64,
    pub compressed: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct LevelInfo {
    pub level: u32,
    pub points: u64,
    pub disk_radius: f32,
    pub support_radius: f32,
}

/// Bytes of `value` as an rkyv archive (a section's raw size).
pub fn archived_len<T>(value: &T) -> Result<u64, FormatError>
where
    T: for<'a> rkyv::Serialize<
        rkyv::api::high::HighSerializer<
            AlignedVec,
            rkyv::ser::allocator::ArenaHandle<'a>,
            rancor::Error,
        >,
    >,
{
    rkyv::to_bytes::<rancor::Error>(value)
        .map(|b| b.len() as u64)
        .map_err(|e| FormatError::Serialize {
            tag: "size".into(),
            detail: e.to_string(),
        })
}

/// Bytes of the basis and its R-trees as stored.
pub fn basis_archived_len(ib: &IndexedBasis) -> Result<u64, FormatError> {
    let trees = RTrees {
        levels: ib.trees.clone(),
    };
    let clip = if ib.clip.is_empty() {
        0
    } else {
        archived_len(&ib.clip)?
    };
    Ok(archived_len(&ib.basis)? + archived_len(&trees)? + clip)
}
