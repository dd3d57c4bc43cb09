//! `ShmPublisher`: writes one payload (header + arrays) in place into a loaned shared-memory
//! sample, sends it, and notifies the person's event service.

use std::mem::MaybeUninit;

use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;

use super::error::{iceoryx, ShmError};
use super::factory::{ShmNode, Svc};
use super::layout::{read_header, Encoder, FrameShape, PayloadBody, PayloadKind, PersonId, Stamp};
use super::loan::{FrameLoan, PayloadLoan};
use super::options::event_service;

/// Publisher of one stream (`lhmpp/<person>/avatar` or `lhmpp/<person>/frame/<camera>`).
///
/// Never blocks on subscribers: the service overwrites the oldest queued sample of a
/// subscriber that does not keep up (safe overflow), and a failed wake-up notification is
/// only logged. Payloads larger than the current segment grow it by powers of two.
#[derive(Debug)]
pub struct ShmPublisher {
    service: String,
    person: PersonId,
    kind: PayloadKind,
    publisher: Publisher<Svc, [u64], ()>,
    notifier: Notifier<Svc>,
}

impl ShmPublisher {
    pub(crate) fn create(
        node: &ShmNode,
        person: &str,
        service: &str,
        kind: PayloadKind,
    ) -> Result<Self, ShmError> {
        let person_id = PersonId::new(person).map_err(|source| ShmError::Layout {
            service: service.to_owned(),
            source,
        })?;
        let pubsub = node.pubsub(service, kind)?;
        let publisher = pubsub
            .publisher_builder()
            .initial_max_slice_len(node.options().initial_capacity.div_ceil(8).max(1))
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .max_loaned_samples(node.options().max_loaned)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(iceoryx(service, "create publisher"))?;
        let events_name = event_service(person)?;
        let notifier = node
            .events(&events_name)?
            .notifier_builder()
            .default_event_id(EventId::new(kind as usize))
            .create()
            .map_err(iceoryx(&events_name, "create notifier"))?;
        tracing::debug!(service, "shared-memory publisher created");
        Ok(Self {
            service: service.to_owned(),
            person: person_id,
            kind,
            publisher,
            notifier,
        })
    }

    /// The service name.
    pub fn service(&self) -> &str {
        &self.service
    }

    /// What this publisher sends.
    pub fn kind(&self) -> PayloadKind {
        self.kind
    }

    /// Validates `body`, loans a sample of exactly the payload size, writes the header and the
    /// arrays straight into it, sends it and wakes listeners. Returns the number of
    /// subscribers it was delivered to.
    pub fn publish(&self, stamp: Stamp, body: &PayloadBody<'_>) -> Result<usize, ShmError> {
        if body.kind() != self.kind {
            return Err(self.wrong_kind(body.kind()));
        }
        let encoder = Encoder::new(&self.person, stamp, body).map_err(|e| self.layout(e))?;
        // Encoded payloads are a multiple of 8 bytes long: whole u64 elements.
        let mut sample = self
            .publisher
            .loan_slice_uninit(encoder.len() / 8)
            .map_err(iceoryx(&self.service, "loan"))?;
        encoder
            .write_into(as_uninit_bytes(sample.payload_mut()))
            .map_err(|e| self.layout(e))?;
        // SAFETY: write_into initialised every byte of the payload.
        let sample = unsafe { sample.assume_init() };
        let delivered = sample.send().map_err(iceoryx(&self.service, "send"))?;
        self.notify();
        Ok(delivered)
    }

    /// Loans a zero-filled sample of `len` bytes (rounded up to whole `u64`s) for the caller
    /// to write a complete payload into; see [`PayloadLoan`].
    pub fn loan_bytes(&self, len: usize) -> Result<PayloadLoan<'_>, ShmError> {
        let mut sample = self
            .publisher
            .loan_slice_uninit(len.div_ceil(8))
            .map_err(iceoryx(&self.service, "loan"))?;
        for word in sample.payload_mut() {
            word.write(0);
        }
        // SAFETY: every word was written above.
        let sample = unsafe { sample.assume_init() };
        Ok(PayloadLoan::new(self, sample, len))
    }

    /// Loans a sample for a frame of `shape` with its header written (person, `stamp`,
    /// sizes, array offsets) and zeroed arrays, so a renderer can write pixels straight into
    /// shared memory and [`FrameLoan::send`] it: no intermediate image buffer, no copy.
    pub fn loan_frame(&self, stamp: Stamp, shape: FrameShape) -> Result<FrameLoan<'_>, ShmError> {
        if self.kind != PayloadKind::Frame {
            return Err(self.wrong_kind(PayloadKind::Frame));
        }
        let header = shape
            .header(&self.person, stamp)
            .map_err(|e| self.layout(e))?;
        let loan = self.loan_bytes(header.total_len as usize)?;
        Ok(FrameLoan::new(loan, header))
    }

    /// Sends an already encoded payload (checked header, then one copy into shared memory).
    /// For forwarding and for benchmarks that share one byte buffer between transports.
    pub fn publish_encoded(&self, payload: &[u8]) -> Result<usize, ShmError> {
        let header = read_header(payload).map_err(|e| self.layout(e))?;
        match PayloadKind::from_u16(header.kind) {
            Some(kind) if kind == self.kind => {}
            Some(kind) => return Err(self.wrong_kind(kind)),
            None => {
                return Err(self.layout(super::layout::LayoutError::BadKind { found: header.kind }))
            }
        }
        let mut sample = self
            .publisher
            .loan_slice_uninit(payload.len().div_ceil(8))
            .map_err(iceoryx(&self.service, "loan"))?;
        let dest = as_uninit_bytes(sample.payload_mut());
        let (body, tail) = dest.split_at_mut(payload.len());
        // SAFETY: `body` and `payload` have the same length and do not overlap.
        unsafe {
            std::ptr::copy_nonoverlapping(payload.as_ptr(), body.as_mut_ptr().cast(), payload.len())
        };
        for d in tail {
            d.write(0);
        }
        // SAFETY: every byte was written above.
        let sample = unsafe { sample.assume_init() };
        let delivered = sample.send().map_err(iceoryx(&self.service, "send"))?;
        self.notify();
        Ok(delivered)
    }

    pub(crate) fn notify(&self) {
        if let Err(e) = self.notifier.notify() {
            // A listener whose socket is full or gone must not stop the publisher.
            tracing::debug!(service = %self.service, error = %e, "wake-up notification failed");
        }
    }

    pub(crate) fn layout(&self, source: super::layout::LayoutError) -> ShmError {
        ShmError::Layout {
            service: self.service.clone(),
            source,
        }
    }

    pub(crate) fn wrong_kind(&self, found: PayloadKind) -> ShmError {
        ShmError::WrongKind {
            service: self.service.clone(),
            expected: self.kind.name(),
            found: found.name(),
        }
    }
}

/// The bytes of a loaned `u64` slice.
fn as_uninit_bytes(words: &mut [MaybeUninit<u64>]) -> &mut [MaybeUninit<u8>] {
    // SAFETY: same memory, u8 has no alignment requirement and MaybeUninit<u8> accepts any
    // (even uninitialised) content; the length is the byte size of `words`.
    unsafe {
        std::slice::from_raw_parts_mut(words.as_mut_ptr().cast(), std::mem::size_of_val(words))
    }
}
