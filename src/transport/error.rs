//! The error type of the shared-memory ports; every variant names the service involved.

use super::layout::LayoutError;
use super::options::ServiceNameError;

/// Errors of [`ShmNode`](super::ShmNode), [`ShmPublisher`](super::ShmPublisher) and
/// [`ShmSubscriber`](super::ShmSubscriber).
#[derive(Debug, thiserror::Error)]
pub enum ShmError {
    /// A person or camera name cannot be part of a service name.
    #[error(transparent)]
    Name(#[from] ServiceNameError),
    /// The payload is inconsistent or not of this layout.
    #[error("service {service}: {source}")]
    Layout {
        /// Service name.
        service: String,
        /// What is wrong with the payload.
        #[source]
        source: LayoutError,
    },
    /// An iceoryx2 call failed (its error type printed as text).
    #[error("service {service}: iceoryx2 {operation} failed: {message}")]
    Iceoryx {
        /// Service (or node) name.
        service: String,
        /// What was attempted (`open publish-subscribe service`, `loan`, `send`, ..).
        operation: &'static str,
        /// iceoryx2's description.
        message: String,
    },
    /// A payload of the wrong kind was given to a publisher.
    #[error("service {service}: publishes {expected} payloads, got a {found}")]
    WrongKind {
        /// Service name.
        service: String,
        /// Kind of the service.
        expected: &'static str,
        /// Kind of the payload.
        found: &'static str,
    },
    /// Registering the listener's file descriptor with tokio failed.
    #[error("service {service}: async wait: {source}")]
    Io {
        /// Service name.
        service: String,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
}

/// Turns any iceoryx2 error into [`ShmError::Iceoryx`] for `service` and `operation`.
pub(crate) fn iceoryx<'a, E: std::fmt::Display>(
    service: &'a str,
    operation: &'static str,
) -> impl FnOnce(E) -> ShmError + 'a {
    move |e| ShmError::Iceoryx {
        service: service.to_owned(),
        operation,
        message: e.to_string(),
    }
}
