//! Loaned shared-memory samples written in place by the producer: [`PayloadLoan`] (raw bytes
//! of any payload) and [`FrameLoan`] (a frame whose header is already written, exposing its
//! pixel, alpha and depth arrays), sent without any further copy.

use iceoryx2::sample_mut::SampleMut;

use super::error::{iceoryx, ShmError};
use super::factory::Svc;
use super::layout::{
    frame_slot, read_header, ArrayRef, LayoutError, PayloadHeader, PayloadKind, HEADER_LEN,
    TIMESTAMP_OFFSET,
};
use super::publisher::ShmPublisher;

/// A zero-filled shared-memory sample of a fixed byte length, loaned from a [`ShmPublisher`].
/// The producer writes a complete payload (header first) into [`PayloadLoan::bytes_mut`];
/// [`PayloadLoan::send`] checks the header and hands the sample to subscribers. Dropping it
/// unsent returns the memory to the publisher.
#[derive(Debug)]
pub struct PayloadLoan<'p> {
    publisher: &'p ShmPublisher,
    sample: SampleMut<Svc, [u64], ()>,
    len: usize,
}

impl<'p> PayloadLoan<'p> {
    pub(crate) fn new(
        publisher: &'p ShmPublisher,
        sample: SampleMut<Svc, [u64], ()>,
        len: usize,
    ) -> Self {
        Self {
            publisher,
            sample,
            len,
        }
    }

    /// The payload bytes (exactly the loaned length; 8-byte aligned).
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        let len = self.len;
        &mut bytemuck::cast_slice_mut::<u64, u8>(self.sample.payload_mut())[..len]
    }

    /// The payload bytes, read-only.
    pub fn bytes(&self) -> &[u8] {
        &bytemuck::cast_slice::<u64, u8>(self.sample.payload())[..self.len]
    }

    /// Checks that the bytes start with a header of this publisher's kind whose `total_len`
    /// fits the sample, sends the sample and wakes listeners. Returns the number of
    /// subscribers it was delivered to.
    pub fn send(self) -> Result<usize, ShmError> {
        let publisher = self.publisher;
        let header = read_header(self.bytes()).map_err(|e| publisher.layout(e))?;
        match PayloadKind::from_u16(header.kind) {
            Some(kind) if kind == publisher.kind() => {}
            Some(kind) => return Err(publisher.wrong_kind(kind)),
            None => return Err(publisher.layout(LayoutError::BadKind { found: header.kind })),
        }
        if header.total_len > self.len as u64 {
            return Err(publisher.layout(LayoutError::Truncated {
                expected: header.total_len,
                actual: self.len as u64,
            }));
        }
        let delivered = self
            .sample
            .send()
            .map_err(iceoryx(publisher.service(), "send"))?;
        publisher.notify();
        Ok(delivered)
    }
}

/// The writable arrays of a [`FrameLoan`], borrowed together.
#[derive(Debug)]
pub struct FrameArraysMut<'a> {
    /// Row-major pixels, `width × height × channels` bytes.
    pub pixels: &'a mut [u8],
    /// Alpha map, `width × height` values, if the shape has one.
    pub alpha: Option<&'a mut [f32]>,
    /// Depth map in metres, `width × height` values, if the shape has one.
    pub depth: Option<&'a mut [f32]>,
}

/// A frame being written straight into shared memory: the header is in place, the arrays are
/// zero until the producer fills them, and [`FrameLoan::send`] publishes it.
#[derive(Debug)]
pub struct FrameLoan<'p> {
    loan: PayloadLoan<'p>,
    header: PayloadHeader,
}

impl<'p> FrameLoan<'p> {
    pub(crate) fn new(mut loan: PayloadLoan<'p>, header: PayloadHeader) -> Self {
        loan.bytes_mut()[..HEADER_LEN].copy_from_slice(bytemuck::bytes_of(&header));
        Self { loan, header }
    }

    /// The header written at the start of the sample.
    pub fn header(&self) -> &PayloadHeader {
        &self.header
    }

    /// Pixels, alpha and depth, borrowed at once so they can be filled in one pass.
    pub fn arrays_mut(&mut self) -> FrameArraysMut<'_> {
        let refs = [
            self.header.arrays[frame_slot::PIXELS],
            self.header.arrays[frame_slot::ALPHA],
            self.header.arrays[frame_slot::DEPTH],
        ];
        let [pixels, alpha, depth] = carve(self.loan.bytes_mut(), refs);
        FrameArraysMut {
            pixels,
            alpha: floats(alpha),
            depth: floats(depth),
        }
    }

    /// The pixel bytes (`width × height × channels`).
    pub fn pixels_mut(&mut self) -> &mut [u8] {
        self.arrays_mut().pixels
    }

    /// Rewrites the header's publish time (e.g. just before sending).
    pub fn set_timestamp_ns(&mut self, timestamp_ns: u64) {
        self.header.timestamp_ns = timestamp_ns;
        self.loan.bytes_mut()[TIMESTAMP_OFFSET..TIMESTAMP_OFFSET + 8]
            .copy_from_slice(&timestamp_ns.to_le_bytes());
    }

    /// Sends the frame and wakes listeners; returns the number of subscribers reached.
    pub fn send(self) -> Result<usize, ShmError> {
        self.loan.send()
    }
}

/// Splits `bytes` into the arrays `refs` describes (ascending, non-overlapping offsets from
/// the payload start; absent arrays come back empty).
fn carve(bytes: &mut [u8], refs: [ArrayRef; 3]) -> [&mut [u8]; 3] {
    let mut out: [&mut [u8]; 3] = Default::default();
    let mut rest = bytes;
    let mut base = 0;
    for (slot, r) in refs.iter().enumerate() {
        if r.len == 0 {
            continue;
        }
        let tail = std::mem::take(&mut rest);
        let (_, from) = tail.split_at_mut(r.offset as usize - base);
        let (array, after) = from.split_at_mut(r.len as usize);
        out[slot] = array;
        rest = after;
        base = (r.offset + r.len) as usize;
    }
    out
}

/// An f32 view of an 8-byte aligned array, `None` when absent.
fn floats(bytes: &mut [u8]) -> Option<&mut [f32]> {
    (!bytes.is_empty()).then(|| bytemuck::cast_slice_mut(bytes))
}
