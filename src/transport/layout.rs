//! The byte layout of one shared-memory payload: a fixed `#[repr(C)]` header followed by
//! attribute arrays, each starting on an 8-byte boundary.
//!
//! This layout is the contract with consumers written in other languages; docs/shm-layout.md
//! describes the same bytes for C and Python readers. All integers and floats are little-endian
//! (the native order of every platform iceoryx2 runs on here).
//!
//! ```text
//! offset size field
//!      0    4 magic          u32  0x504D484C, the bytes "LHMP"
//!      4    2 version        u16  LAYOUT_VERSION (1)
//!      6    2 kind           u16  1 = avatar, 2 = frame
//!      8    4 header_len     u32  size of this header in bytes (224)
//!     12    4 array_slots    u32  number of entries in `arrays` (8)
//!     16   32 person_id      u8[32] UTF-8, zero padded
//!     48    8 revision       u64  avatar revision / frame sequence number
//!     56    8 timestamp_ns   u64  publish time, CLOCK_REALTIME nanoseconds since the Unix epoch
//!     64    8 total_len      u64  bytes of header + arrays + padding
//!     72    4 gaussians      u32  avatar: number of Gaussians (0 for frames)
//!     76    4 sh_coeffs      u32  avatar: colour coefficients per Gaussian and channel (1 = RGB)
//!     80    4 width          u32  frame: pixels per row (0 for avatars)
//!     84    4 height         u32  frame: rows (0 for avatars)
//!     88    4 channels       u32  frame: 3 = rgb8, 4 = rgba8 (0 for avatars)
//!     92    4 flags          u32  avatar: bit 0 = colours are latent features (FLAG_RGB_LATENT);
//!                                 other bits and frames: 0
//!     96  128 arrays         8 × { offset u64, len u64 }, byte offset from the payload start
//!                            and byte length; len 0 = array absent
//! ```
//!
//! Avatar slots: 0 positions f32×3, 1 scales f32×3, 2 rotations f32×4 (w x y z), 3 opacities f32,
//! 4 colours f32×3×sh_coeffs (per Gaussian: coefficient-major, RGB inner), 5 skinning bones u16×4,
//! 6 skinning weights f32×4, 7 unused.
//! Frame slots: 0 pixels u8 (row-major, `channels` per pixel), 1 alpha f32 (optional),
//! 2 depth f32 (optional, metres), 3..7 unused.

use std::mem::MaybeUninit;

use bytemuck::{Pod, Zeroable};

use super::checksum::Fnv1a64;

/// `b"LHMP"` read as a little-endian u32.
pub const MAGIC: u32 = u32::from_le_bytes(*b"LHMP");
/// Version of this layout; bumped on any incompatible change.
pub const LAYOUT_VERSION: u16 = 1;
/// Avatar header flag: the colours are latent features of a checkpoint whose Gaussian RGB is
/// not display-ready (LHMPP-700M, LHMPPS-700M); render them through its neural renderer.
pub const FLAG_RGB_LATENT: u32 = 1;
/// Byte offset of `revision` in the header (the sequence number a reader checks first).
pub const REVISION_OFFSET: usize = std::mem::offset_of!(PayloadHeader, revision);
/// Byte offset of `timestamp_ns` in the header.
pub const TIMESTAMP_OFFSET: usize = std::mem::offset_of!(PayloadHeader, timestamp_ns);
/// Number of array descriptors in every header.
pub const ARRAY_SLOTS: usize = 8;
/// Every array starts at a multiple of this many bytes from the payload start.
pub const ARRAY_ALIGN: usize = 8;
/// Bytes reserved for the person id in the header.
pub const PERSON_ID_LEN: usize = 32;
/// Size of [`PayloadHeader`] in bytes.
pub const HEADER_LEN: usize = std::mem::size_of::<PayloadHeader>();

/// Avatar array slots (indices into [`PayloadHeader::arrays`]).
pub mod avatar_slot {
    /// Positions, f32×3 per Gaussian.
    pub const POSITIONS: usize = 0;
    /// Scales, f32×3 per Gaussian.
    pub const SCALES: usize = 1;
    /// Rotations as unit quaternions w x y z, f32×4 per Gaussian.
    pub const ROTATIONS: usize = 2;
    /// Opacities, one f32 per Gaussian.
    pub const OPACITIES: usize = 3;
    /// Colours, f32×3×sh_coeffs per Gaussian.
    pub const COLOURS: usize = 4;
    /// Skinning bone indices, u16×4 per Gaussian.
    pub const BONES: usize = 5;
    /// Skinning weights, f32×4 per Gaussian.
    pub const WEIGHTS: usize = 6;
}

/// Frame array slots (indices into [`PayloadHeader::arrays`]).
pub mod frame_slot {
    /// Pixels, u8 × channels per pixel, row-major.
    pub const PIXELS: usize = 0;
    /// Optional alpha, one f32 per pixel.
    pub const ALPHA: usize = 1;
    /// Optional depth in metres, one f32 per pixel.
    pub const DEPTH: usize = 2;
}

/// What a payload carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u16)]
pub enum PayloadKind {
    /// Canonical Gaussian avatar with skinning.
    Avatar = 1,
    /// Rendered image (rgb8 or rgba8) with optional alpha and depth.
    Frame = 2,
}

impl PayloadKind {
    /// The kind written as `kind` in the header, or `None` for an unknown value.
    pub fn from_u16(value: u16) -> Option<Self> {
        match value {
            1 => Some(Self::Avatar),
            2 => Some(Self::Frame),
            _ => None,
        }
    }

    /// Lower-case name (`avatar`, `frame`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Avatar => "avatar",
            Self::Frame => "frame",
        }
    }
}

/// Where one attribute array lies in the payload (bytes from the payload start).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Pod, Zeroable)]
#[repr(C)]
pub struct ArrayRef {
    /// Byte offset from the start of the payload; a multiple of [`ARRAY_ALIGN`].
    pub offset: u64,
    /// Length in bytes; 0 when the array is absent.
    pub len: u64,
}

/// The fixed header at the start of every payload (224 bytes, no implicit padding).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable)]
#[repr(C)]
pub struct PayloadHeader {
    /// [`MAGIC`].
    pub magic: u32,
    /// [`LAYOUT_VERSION`].
    pub version: u16,
    /// [`PayloadKind`] as u16.
    pub kind: u16,
    /// [`HEADER_LEN`].
    pub header_len: u32,
    /// [`ARRAY_SLOTS`].
    pub array_slots: u32,
    /// Person id, UTF-8, zero padded.
    pub person_id: [u8; PERSON_ID_LEN],
    /// Avatar revision or frame sequence number.
    pub revision: u64,
    /// Publish time in nanoseconds since the Unix epoch (CLOCK_REALTIME).
    pub timestamp_ns: u64,
    /// Bytes of the whole payload (header, arrays, padding).
    pub total_len: u64,
    /// Avatar: number of Gaussians.
    pub gaussians: u32,
    /// Avatar: colour coefficients per Gaussian and channel (1 = plain RGB).
    pub sh_coeffs: u32,
    /// Frame: width in pixels.
    pub width: u32,
    /// Frame: height in pixels.
    pub height: u32,
    /// Frame: bytes per pixel in the pixel array (3 = rgb8, 4 = rgba8).
    pub channels: u32,
    /// Avatar: [`FLAG_RGB_LATENT`] when the colours are not display-ready; otherwise 0.
    pub flags: u32,
    /// Array descriptors; see [`avatar_slot`] and [`frame_slot`].
    pub arrays: [ArrayRef; ARRAY_SLOTS],
}

/// Errors found while encoding or decoding a payload; each names the offending field.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum LayoutError {
    /// The person id does not fit the header or is not a plain name.
    #[error("person id {id:?}: must be 1..=32 bytes of [A-Za-z0-9_-]")]
    BadPersonId {
        /// The rejected id.
        id: String,
    },
    /// An array's length disagrees with the element counts.
    #[error("{kind} array `{array}`: expected {expected} elements, got {actual}")]
    CountMismatch {
        /// `avatar` or `frame`.
        kind: &'static str,
        /// Array name.
        array: &'static str,
        /// Elements implied by the counts.
        expected: usize,
        /// Elements supplied.
        actual: usize,
    },
    /// A count in the header or the view is outside what the layout supports.
    #[error("field `{field}` = {value} is not supported ({why})")]
    BadCount {
        /// Field name.
        field: &'static str,
        /// Its value.
        value: u64,
        /// What is allowed.
        why: &'static str,
    },
    /// The payload is shorter than the header or than `total_len`.
    #[error("payload of {actual} bytes is shorter than the {expected} bytes it declares")]
    Truncated {
        /// Bytes needed.
        expected: u64,
        /// Bytes present.
        actual: u64,
    },
    /// The payload does not start with the `LHMP` magic.
    #[error("payload magic is {found:#010x}, expected {MAGIC:#010x} (\"LHMP\")")]
    BadMagic {
        /// The value found.
        found: u32,
    },
    /// The payload was written with another layout version.
    #[error("payload layout version {found}, this reader understands {LAYOUT_VERSION}")]
    BadVersion {
        /// The version found.
        found: u16,
    },
    /// The header's kind is neither avatar nor frame.
    #[error("payload kind {found} is unknown (1 = avatar, 2 = frame)")]
    BadKind {
        /// The value found.
        found: u16,
    },
    /// An array descriptor points outside the payload or is misaligned.
    #[error("array slot {slot}: offset {offset} + len {len} is outside the {total} byte payload or not {ARRAY_ALIGN}-byte aligned")]
    BadArray {
        /// Slot index.
        slot: usize,
        /// Declared offset.
        offset: u64,
        /// Declared length.
        len: u64,
        /// Payload length.
        total: u64,
    },
    /// The destination buffer does not match the encoded length.
    #[error("destination buffer has {actual} bytes, the payload needs {expected}")]
    BufferSize {
        /// Bytes needed.
        expected: usize,
        /// Bytes supplied.
        actual: usize,
    },
}

/// A person id as stored in the header: 1..=32 bytes of `[A-Za-z0-9_-]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PersonId {
    bytes: [u8; PERSON_ID_LEN],
    len: usize,
}

impl PersonId {
    /// Checks and stores `id`.
    pub fn new(id: &str) -> Result<Self, LayoutError> {
        let ok = !id.is_empty()
            && id.len() <= PERSON_ID_LEN
            && id
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
        if !ok {
            return Err(LayoutError::BadPersonId { id: id.to_owned() });
        }
        let mut bytes = [0u8; PERSON_ID_LEN];
        bytes[..id.len()].copy_from_slice(id.as_bytes());
        Ok(Self {
            bytes,
            len: id.len(),
        })
    }

    fn from_header(raw: &[u8; PERSON_ID_LEN]) -> Result<Self, LayoutError> {
        let len = raw.iter().position(|&b| b == 0).unwrap_or(PERSON_ID_LEN);
        let text = std::str::from_utf8(&raw[..len]).map_err(|_| LayoutError::BadPersonId {
            id: String::from_utf8_lossy(&raw[..len]).into_owned(),
        })?;
        Self::new(text)
    }

    /// The id as text.
    pub fn as_str(&self) -> &str {
        // Only ASCII bytes are ever stored.
        std::str::from_utf8(&self.bytes[..self.len]).unwrap_or_default()
    }
}

impl std::fmt::Display for PersonId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Identity and time of one payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stamp {
    /// Avatar revision or frame sequence number.
    pub revision: u64,
    /// Nanoseconds since the Unix epoch (CLOCK_REALTIME).
    pub timestamp_ns: u64,
}

impl Stamp {
    /// A stamp carrying the current wall-clock time.
    pub fn now(revision: u64) -> Self {
        Self {
            revision,
            timestamp_ns: unix_time_ns(),
        }
    }
}

/// Nanoseconds since the Unix epoch from the system clock (0 if the clock is before 1970).
pub fn unix_time_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

/// A Gaussian avatar as borrowed arrays, all of length [`AvatarView::gaussians`] (colours:
/// `gaussians * sh_coeffs * 3`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AvatarView<'a> {
    /// Gaussian centres.
    pub positions: &'a [[f32; 3]],
    /// Per-axis scales.
    pub scales: &'a [[f32; 3]],
    /// Unit quaternions, w x y z.
    pub rotations: &'a [[f32; 4]],
    /// Opacities in 0..=1.
    pub opacities: &'a [f32],
    /// Colour coefficients per channel (1 = plain RGB).
    pub sh_coeffs: u32,
    /// Colours: per Gaussian `sh_coeffs` coefficients of RGB.
    pub colours: &'a [f32],
    /// Skinning bone indices.
    pub bones: &'a [[u16; 4]],
    /// Skinning weights.
    pub weights: &'a [[f32; 4]],
    /// The colours are latent features, not display-ready RGB (header flag
    /// [`FLAG_RGB_LATENT`]): a viewer must not show them as colours.
    pub rgb_latent: bool,
}

impl<'a> AvatarView<'a> {
    /// Number of Gaussians.
    pub fn gaussians(&self) -> usize {
        self.positions.len()
    }

    fn arrays(&self) -> [&'a [u8]; ARRAY_SLOTS] {
        [
            bytemuck::cast_slice(self.positions),
            bytemuck::cast_slice(self.scales),
            bytemuck::cast_slice(self.rotations),
            bytemuck::cast_slice(self.opacities),
            bytemuck::cast_slice(self.colours),
            bytemuck::cast_slice(self.bones),
            bytemuck::cast_slice(self.weights),
            &[],
        ]
    }

    fn validate(&self) -> Result<(), LayoutError> {
        let n = self.gaussians();
        check_u32("gaussians", n as u64)?;
        if self.sh_coeffs == 0 || self.sh_coeffs > 64 {
            return Err(LayoutError::BadCount {
                field: "sh_coeffs",
                value: self.sh_coeffs as u64,
                why: "1..=64",
            });
        }
        let counts = [
            ("scales", self.scales.len(), n),
            ("rotations", self.rotations.len(), n),
            ("opacities", self.opacities.len(), n),
            (
                "colours",
                self.colours.len(),
                n * self.sh_coeffs as usize * 3,
            ),
            ("bones", self.bones.len(), n),
            ("weights", self.weights.len(), n),
        ];
        for (array, actual, expected) in counts {
            if actual != expected {
                return Err(LayoutError::CountMismatch {
                    kind: "avatar",
                    array,
                    expected,
                    actual,
                });
            }
        }
        Ok(())
    }

    /// FNV-1a 64 over the bytes of every array in slot order (padding excluded).
    pub fn checksum(&self) -> u64 {
        checksum_arrays(&self.arrays())
    }
}

/// A rendered image as borrowed arrays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameView<'a> {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Bytes per pixel: 3 (rgb8) or 4 (rgba8).
    pub channels: u32,
    /// Row-major pixels, `width * height * channels` bytes.
    pub pixels: &'a [u8],
    /// Optional alpha, `width * height` values.
    pub alpha: Option<&'a [f32]>,
    /// Optional depth in metres, `width * height` values.
    pub depth: Option<&'a [f32]>,
}

impl<'a> FrameView<'a> {
    fn arrays(&self) -> [&'a [u8]; ARRAY_SLOTS] {
        let mut arrays: [&'a [u8]; ARRAY_SLOTS] = [&[]; ARRAY_SLOTS];
        arrays[frame_slot::PIXELS] = self.pixels;
        arrays[frame_slot::ALPHA] = bytemuck::cast_slice(self.alpha.unwrap_or(&[]));
        arrays[frame_slot::DEPTH] = bytemuck::cast_slice(self.depth.unwrap_or(&[]));
        arrays
    }

    fn validate(&self) -> Result<(), LayoutError> {
        if self.channels != 3 && self.channels != 4 {
            return Err(LayoutError::BadCount {
                field: "channels",
                value: self.channels as u64,
                why: "3 (rgb8) or 4 (rgba8)",
            });
        }
        let pixels = self.width as usize * self.height as usize;
        let mut counts = vec![("pixels", self.pixels.len(), pixels * self.channels as usize)];
        if let Some(alpha) = self.alpha {
            counts.push(("alpha", alpha.len(), pixels));
        }
        if let Some(depth) = self.depth {
            counts.push(("depth", depth.len(), pixels));
        }
        for (array, actual, expected) in counts {
            if actual != expected {
                return Err(LayoutError::CountMismatch {
                    kind: "frame",
                    array,
                    expected,
                    actual,
                });
            }
        }
        Ok(())
    }

    /// FNV-1a 64 over the bytes of every present array in slot order (padding excluded).
    pub fn checksum(&self) -> u64 {
        checksum_arrays(&self.arrays())
    }
}

/// The content of a payload: an avatar or a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PayloadBody<'a> {
    /// Gaussian avatar.
    Avatar(AvatarView<'a>),
    /// Rendered image.
    Frame(FrameView<'a>),
}

impl<'a> PayloadBody<'a> {
    /// The kind written in the header.
    pub fn kind(&self) -> PayloadKind {
        match self {
            Self::Avatar(_) => PayloadKind::Avatar,
            Self::Frame(_) => PayloadKind::Frame,
        }
    }

    /// FNV-1a 64 over the arrays (see [`AvatarView::checksum`], [`FrameView::checksum`]).
    pub fn checksum(&self) -> u64 {
        match self {
            Self::Avatar(a) => a.checksum(),
            Self::Frame(f) => f.checksum(),
        }
    }

    fn arrays(&self) -> [&'a [u8]; ARRAY_SLOTS] {
        match self {
            Self::Avatar(a) => a.arrays(),
            Self::Frame(f) => f.arrays(),
        }
    }

    fn validate(&self) -> Result<(), LayoutError> {
        match self {
            Self::Avatar(a) => a.validate(),
            Self::Frame(f) => f.validate(),
        }
    }
}

/// A payload read back from bytes: header fields plus borrowed arrays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decoded<'a> {
    /// Person the payload belongs to.
    pub person: PersonId,
    /// Revision and publish time.
    pub stamp: Stamp,
    /// The arrays.
    pub body: PayloadBody<'a>,
}

fn checksum_arrays(arrays: &[&[u8]]) -> u64 {
    let mut hash = Fnv1a64::new();
    for array in arrays {
        hash.write(array);
    }
    hash.finish()
}

fn check_u32(field: &'static str, value: u64) -> Result<(), LayoutError> {
    if value > u32::MAX as u64 {
        return Err(LayoutError::BadCount {
            field,
            value,
            why: "must fit in u32",
        });
    }
    Ok(())
}

fn align_up(value: usize) -> usize {
    value.div_ceil(ARRAY_ALIGN) * ARRAY_ALIGN
}

/// Element counts written in the header (zero where they do not apply to the kind).
#[derive(Debug, Clone, Copy, Default)]
struct Counts {
    gaussians: u32,
    sh_coeffs: u32,
    width: u32,
    height: u32,
    channels: u32,
    flags: u32,
}

/// The header of a payload whose arrays have the byte lengths `lens` (0 = absent), each
/// placed after the previous one on the next 8-byte boundary.
fn lay_out(
    person: &PersonId,
    stamp: Stamp,
    kind: PayloadKind,
    lens: [usize; ARRAY_SLOTS],
    counts: Counts,
) -> PayloadHeader {
    let mut refs = [ArrayRef::default(); ARRAY_SLOTS];
    let mut cursor = HEADER_LEN;
    for (slot, len) in lens.into_iter().enumerate() {
        if len == 0 {
            continue;
        }
        refs[slot] = ArrayRef {
            offset: cursor as u64,
            len: len as u64,
        };
        cursor = align_up(cursor + len);
    }
    PayloadHeader {
        magic: MAGIC,
        version: LAYOUT_VERSION,
        kind: kind as u16,
        header_len: HEADER_LEN as u32,
        array_slots: ARRAY_SLOTS as u32,
        person_id: person.bytes,
        revision: stamp.revision,
        timestamp_ns: stamp.timestamp_ns,
        total_len: cursor as u64,
        gaussians: counts.gaussians,
        sh_coeffs: counts.sh_coeffs,
        width: counts.width,
        height: counts.height,
        channels: counts.channels,
        flags: counts.flags,
        arrays: refs,
    }
}

/// The shape of a frame to be written in place (see `ShmPublisher::loan_frame`): its size,
/// bytes per pixel and which optional float maps it carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameShape {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Bytes per pixel: 3 (rgb8) or 4 (rgba8).
    pub channels: u32,
    /// Whether the payload carries an f32 alpha map.
    pub alpha: bool,
    /// Whether the payload carries an f32 depth map.
    pub depth: bool,
}

impl FrameShape {
    /// An rgb8 frame without alpha or depth.
    pub fn rgb8(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            channels: 3,
            alpha: false,
            depth: false,
        }
    }

    /// The header of a frame of this shape: the same bytes [`Encoder::new`] writes for a
    /// [`FrameView`] with these sizes. Fails on a channel count other than 3 or 4 or a
    /// size whose byte length overflows.
    pub fn header(&self, person: &PersonId, stamp: Stamp) -> Result<PayloadHeader, LayoutError> {
        if self.channels != 3 && self.channels != 4 {
            return Err(LayoutError::BadCount {
                field: "channels",
                value: self.channels as u64,
                why: "3 (rgb8) or 4 (rgba8)",
            });
        }
        let pixels = (self.width as usize)
            .checked_mul(self.height as usize)
            .filter(|p| p.checked_mul(4 * 3).is_some())
            .ok_or(LayoutError::BadCount {
                field: "width × height",
                value: self.width as u64 * self.height as u64,
                why: "byte size must fit in memory",
            })?;
        let mut lens = [0; ARRAY_SLOTS];
        lens[frame_slot::PIXELS] = pixels * self.channels as usize;
        lens[frame_slot::ALPHA] = if self.alpha { 4 * pixels } else { 0 };
        lens[frame_slot::DEPTH] = if self.depth { 4 * pixels } else { 0 };
        let counts = Counts {
            width: self.width,
            height: self.height,
            channels: self.channels,
            ..Counts::default()
        };
        Ok(lay_out(person, stamp, PayloadKind::Frame, lens, counts))
    }
}

/// A checked payload ready to be written: header computed, arrays borrowed.
#[derive(Debug, Clone, Copy)]
pub struct Encoder<'a> {
    header: PayloadHeader,
    arrays: [&'a [u8]; ARRAY_SLOTS],
}

impl<'a> Encoder<'a> {
    /// Validates `body` and lays out its header; fails naming the first inconsistent array.
    pub fn new(
        person: &PersonId,
        stamp: Stamp,
        body: &PayloadBody<'a>,
    ) -> Result<Self, LayoutError> {
        body.validate()?;
        let arrays = body.arrays();
        let counts = match body {
            PayloadBody::Avatar(a) => Counts {
                gaussians: a.gaussians() as u32,
                sh_coeffs: a.sh_coeffs,
                flags: if a.rgb_latent { FLAG_RGB_LATENT } else { 0 },
                ..Counts::default()
            },
            PayloadBody::Frame(f) => Counts {
                width: f.width,
                height: f.height,
                channels: f.channels,
                ..Counts::default()
            },
        };
        let header = lay_out(person, stamp, body.kind(), arrays.map(|a| a.len()), counts);
        Ok(Self { header, arrays })
    }

    /// Bytes the payload occupies.
    pub fn len(&self) -> usize {
        self.header.total_len as usize
    }

    /// Always false: a payload holds at least its header.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The header that will be written.
    pub fn header(&self) -> &PayloadHeader {
        &self.header
    }

    /// Writes header, arrays and zeroed padding into `dest` (exactly [`Encoder::len`] bytes),
    /// initialising every byte. This is how a loaned shared-memory sample is filled in place.
    pub fn write_into(&self, dest: &mut [MaybeUninit<u8>]) -> Result<(), LayoutError> {
        if dest.len() != self.len() {
            return Err(LayoutError::BufferSize {
                expected: self.len(),
                actual: dest.len(),
            });
        }
        copy_bytes(&mut dest[..HEADER_LEN], bytemuck::bytes_of(&self.header));
        let mut cursor = HEADER_LEN;
        for (slot, array) in self.arrays.iter().enumerate() {
            if array.is_empty() {
                continue;
            }
            let start = self.header.arrays[slot].offset as usize;
            let end = start + array.len();
            copy_bytes(&mut dest[start..end], array);
            let padded = align_up(end);
            zero_bytes(&mut dest[end..padded]);
            cursor = padded;
        }
        debug_assert_eq!(cursor, self.len());
        Ok(())
    }

    /// Encodes into a new vector (tests, benches and non-shared-memory transports).
    pub fn to_vec(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.len());
        self.write_into(&mut out.spare_capacity_mut()[..self.len()])
            .expect("buffer sized from the header");
        // SAFETY: write_into initialised exactly `len` bytes.
        unsafe { out.set_len(self.len()) };
        out
    }
}

fn copy_bytes(dest: &mut [MaybeUninit<u8>], src: &[u8]) {
    debug_assert_eq!(dest.len(), src.len());
    // SAFETY: same length, distinct allocations (src is borrowed immutably while dest is
    // borrowed mutably), and MaybeUninit<u8> has the layout of u8.
    unsafe {
        std::ptr::copy_nonoverlapping(src.as_ptr(), dest.as_mut_ptr().cast::<u8>(), src.len());
    }
}

fn zero_bytes(dest: &mut [MaybeUninit<u8>]) {
    for byte in dest {
        byte.write(0);
    }
}

/// Reads the header of `bytes` without checking the arrays.
pub fn read_header(bytes: &[u8]) -> Result<PayloadHeader, LayoutError> {
    if bytes.len() < HEADER_LEN {
        return Err(LayoutError::Truncated {
            expected: HEADER_LEN as u64,
            actual: bytes.len() as u64,
        });
    }
    let header: PayloadHeader = bytemuck::pod_read_unaligned(&bytes[..HEADER_LEN]);
    if header.magic != MAGIC {
        return Err(LayoutError::BadMagic {
            found: header.magic,
        });
    }
    if header.version != LAYOUT_VERSION {
        return Err(LayoutError::BadVersion {
            found: header.version,
        });
    }
    Ok(header)
}

/// Decodes a payload, borrowing its arrays from `bytes` (no copy). `bytes` must start on an
/// 8-byte boundary, as iceoryx2 samples of this transport do; a misaligned buffer is rejected.
pub fn decode(bytes: &[u8]) -> Result<Decoded<'_>, LayoutError> {
    let header = read_header(bytes)?;
    let kind =
        PayloadKind::from_u16(header.kind).ok_or(LayoutError::BadKind { found: header.kind })?;
    if (bytes.len() as u64) < header.total_len {
        return Err(LayoutError::Truncated {
            expected: header.total_len,
            actual: bytes.len() as u64,
        });
    }
    let total = header.total_len;
    let mut arrays: [&[u8]; ARRAY_SLOTS] = [&[]; ARRAY_SLOTS];
    for (slot, r) in header.arrays.iter().enumerate() {
        if r.len == 0 {
            continue;
        }
        let end = r.offset.checked_add(r.len);
        let aligned = (bytes.as_ptr() as usize + r.offset as usize) % ARRAY_ALIGN == 0;
        match end {
            Some(end) if end <= total && r.offset >= HEADER_LEN as u64 && aligned => {
                arrays[slot] = &bytes[r.offset as usize..end as usize];
            }
            _ => {
                return Err(LayoutError::BadArray {
                    slot,
                    offset: r.offset,
                    len: r.len,
                    total,
                })
            }
        }
    }
    let person = PersonId::from_header(&header.person_id)?;
    let stamp = Stamp {
        revision: header.revision,
        timestamp_ns: header.timestamp_ns,
    };
    let body = match kind {
        PayloadKind::Avatar => PayloadBody::Avatar(decode_avatar(&header, &arrays)?),
        PayloadKind::Frame => PayloadBody::Frame(decode_frame(&header, &arrays)?),
    };
    Ok(Decoded {
        person,
        stamp,
        body,
    })
}

fn cast<'a, T: Pod>(arrays: &[&'a [u8]], slot: usize, total: u64) -> Result<&'a [T], LayoutError> {
    bytemuck::try_cast_slice(arrays[slot]).map_err(|_| LayoutError::BadArray {
        slot,
        offset: 0,
        len: arrays[slot].len() as u64,
        total,
    })
}

fn decode_avatar<'a>(
    header: &PayloadHeader,
    arrays: &[&'a [u8]; ARRAY_SLOTS],
) -> Result<AvatarView<'a>, LayoutError> {
    use avatar_slot::*;
    let t = header.total_len;
    let view = AvatarView {
        positions: cast(arrays, POSITIONS, t)?,
        scales: cast(arrays, SCALES, t)?,
        rotations: cast(arrays, ROTATIONS, t)?,
        opacities: cast(arrays, OPACITIES, t)?,
        sh_coeffs: header.sh_coeffs,
        colours: cast(arrays, COLOURS, t)?,
        bones: cast(arrays, BONES, t)?,
        weights: cast(arrays, WEIGHTS, t)?,
        rgb_latent: header.flags & FLAG_RGB_LATENT != 0,
    };
    if view.gaussians() != header.gaussians as usize {
        return Err(LayoutError::CountMismatch {
            kind: "avatar",
            array: "positions",
            expected: header.gaussians as usize,
            actual: view.gaussians(),
        });
    }
    view.validate()?;
    Ok(view)
}

fn decode_frame<'a>(
    header: &PayloadHeader,
    arrays: &[&'a [u8]; ARRAY_SLOTS],
) -> Result<FrameView<'a>, LayoutError> {
    use frame_slot::*;
    let t = header.total_len;
    let optional = |slot: usize| -> Result<Option<&'a [f32]>, LayoutError> {
        Ok(if arrays[slot].is_empty() {
            None
        } else {
            Some(cast(arrays, slot, t)?)
        })
    };
    let view = FrameView {
        width: header.width,
        height: header.height,
        channels: header.channels,
        pixels: arrays[PIXELS],
        alpha: optional(ALPHA)?,
        depth: optional(DEPTH)?,
    };
    view.validate()?;
    Ok(view)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn aligned(bytes: &[u8]) -> Vec<u64> {
        let mut words = vec![0u64; bytes.len().div_ceil(8)];
        bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
        words
    }

    struct Avatar {
        positions: Vec<[f32; 3]>,
        scales: Vec<[f32; 3]>,
        rotations: Vec<[f32; 4]>,
        opacities: Vec<f32>,
        colours: Vec<f32>,
        bones: Vec<[u16; 4]>,
        weights: Vec<[f32; 4]>,
    }

    fn avatar(n: usize) -> Avatar {
        let f = |i: usize, k: usize| (i * 7 + k) as f32 * 0.5;
        Avatar {
            positions: (0..n).map(|i| [f(i, 0), f(i, 1), f(i, 2)]).collect(),
            scales: (0..n).map(|i| [f(i, 3), f(i, 4), f(i, 5)]).collect(),
            rotations: (0..n).map(|i| [1.0, 0.0, f(i, 6), 0.0]).collect(),
            opacities: (0..n).map(|i| f(i, 8)).collect(),
            colours: (0..n * 3).map(|i| f(i, 9)).collect(),
            bones: (0..n).map(|i| [i as u16, 1, 2, 3]).collect(),
            weights: (0..n).map(|_| [0.25; 4]).collect(),
        }
    }

    fn view(a: &Avatar) -> AvatarView<'_> {
        AvatarView {
            positions: &a.positions,
            scales: &a.scales,
            rotations: &a.rotations,
            opacities: &a.opacities,
            sh_coeffs: 1,
            colours: &a.colours,
            bones: &a.bones,
            weights: &a.weights,
            rgb_latent: false,
        }
    }

    #[test]
    fn the_latent_rgb_flag_is_bit_0_at_byte_92_and_round_trips() {
        let a = avatar(3);
        let person = PersonId::new("p").unwrap();
        for latent in [false, true] {
            let v = AvatarView {
                rgb_latent: latent,
                ..view(&a)
            };
            let stamp = Stamp {
                revision: 1,
                timestamp_ns: 2,
            };
            let bytes = Encoder::new(&person, stamp, &PayloadBody::Avatar(v))
                .unwrap()
                .to_vec();
            assert_eq!(bytes[92], u8::from(latent));
            let words = aligned(&bytes);
            match decode(&bytemuck::cast_slice(&words)[..bytes.len()])
                .unwrap()
                .body
            {
                PayloadBody::Avatar(d) => assert_eq!(d.rgb_latent, latent),
                PayloadBody::Frame(_) => panic!("decoded a frame"),
            }
        }
    }

    #[test]
    fn header_is_224_bytes_with_arrays_at_96() {
        assert_eq!(HEADER_LEN, 224);
        assert_eq!(std::mem::offset_of!(PayloadHeader, person_id), 16);
        assert_eq!(std::mem::offset_of!(PayloadHeader, timestamp_ns), 56);
        assert_eq!(std::mem::offset_of!(PayloadHeader, gaussians), 72);
        assert_eq!(std::mem::offset_of!(PayloadHeader, arrays), 96);
        assert_eq!(&MAGIC.to_le_bytes(), b"LHMP");
    }

    #[test]
    fn avatar_round_trips_with_aligned_arrays() {
        let a = avatar(5); // odd count: opacities (20 bytes) need padding
        let person = PersonId::new("alice").unwrap();
        let enc = Encoder::new(
            &person,
            Stamp {
                revision: 9,
                timestamp_ns: 42,
            },
            &PayloadBody::Avatar(view(&a)),
        )
        .unwrap();
        let bytes = enc.to_vec();
        assert_eq!(&bytes[..4], b"LHMP");
        for r in enc.header().arrays.iter().filter(|r| r.len > 0) {
            assert_eq!(r.offset % 8, 0);
        }
        let words = aligned(&bytes);
        let decoded = decode(&bytemuck::cast_slice(&words)[..bytes.len()]).unwrap();
        assert_eq!(decoded.person.as_str(), "alice");
        assert_eq!(
            decoded.stamp,
            Stamp {
                revision: 9,
                timestamp_ns: 42
            }
        );
        assert_eq!(decoded.body, PayloadBody::Avatar(view(&a)));
        assert_eq!(decoded.body.checksum(), view(&a).checksum());
    }

    #[test]
    fn frame_round_trips_with_optional_depth_only() {
        let pixels: Vec<u8> = (0..3 * 2 * 3).map(|i| i as u8).collect();
        let depth = vec![1.5f32; 6];
        let frame = FrameView {
            width: 3,
            height: 2,
            channels: 3,
            pixels: &pixels,
            alpha: None,
            depth: Some(&depth),
        };
        let person = PersonId::new("bob").unwrap();
        let bytes = Encoder::new(&person, Stamp::now(1), &PayloadBody::Frame(frame))
            .unwrap()
            .to_vec();
        let words = aligned(&bytes);
        let decoded = decode(&bytemuck::cast_slice(&words)[..bytes.len()]).unwrap();
        assert_eq!(decoded.body, PayloadBody::Frame(frame));
    }

    #[test]
    fn mismatched_array_is_named() {
        let mut a = avatar(4);
        a.weights.pop();
        let err = Encoder::new(
            &PersonId::new("p").unwrap(),
            Stamp::now(0),
            &PayloadBody::Avatar(view(&a)),
        )
        .unwrap_err();
        assert_eq!(
            err,
            LayoutError::CountMismatch {
                kind: "avatar",
                array: "weights",
                expected: 4,
                actual: 3
            }
        );
    }

    #[test]
    fn corrupt_payloads_are_rejected_not_read() {
        let a = avatar(3);
        let bytes = Encoder::new(
            &PersonId::new("p").unwrap(),
            Stamp::now(0),
            &PayloadBody::Avatar(view(&a)),
        )
        .unwrap()
        .to_vec();
        let words = aligned(&bytes);
        let good: &[u8] = &bytemuck::cast_slice(&words)[..bytes.len()];
        assert!(matches!(
            decode(&good[..100]),
            Err(LayoutError::Truncated { .. })
        ));
        assert!(matches!(
            decode(&good[..good.len() - 8]),
            Err(LayoutError::Truncated { .. })
        ));
        let mut bad = words.clone();
        bytemuck::cast_slice_mut::<u64, u8>(&mut bad)[0] = b'X';
        assert!(matches!(
            decode(bytemuck::cast_slice(&bad)),
            Err(LayoutError::BadMagic { .. })
        ));
        let mut bad = words.clone();
        // arrays[0].offset points past the end.
        bytemuck::cast_slice_mut::<u64, u8>(&mut bad)[96..104]
            .copy_from_slice(&(1u64 << 40).to_le_bytes());
        assert!(matches!(
            decode(bytemuck::cast_slice(&bad)),
            Err(LayoutError::BadArray { slot: 0, .. })
        ));
    }

    #[test]
    fn person_ids_that_do_not_fit_are_rejected() {
        assert!(PersonId::new("").is_err());
        assert!(PersonId::new(&"x".repeat(33)).is_err());
        assert!(PersonId::new("a/b").is_err());
        assert_eq!(PersonId::new(&"x".repeat(32)).unwrap().as_str().len(), 32);
    }

    #[test]
    fn checksum_changes_when_one_value_changes() {
        let mut a = avatar(8);
        let before = view(&a).checksum();
        a.weights[7][3] = 0.5;
        assert_ne!(view(&a).checksum(), before);
    }
}
