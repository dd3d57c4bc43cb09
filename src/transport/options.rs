//! Sizing of the shared-memory services and the names they are published under.
//!
//! iceoryx2 preallocates the worst case: every publisher reserves
//! `max_subscribers * (subscriber_buffer + subscriber_max_borrowed) + history + max_loaned`
//! samples of the largest payload. The defaults keep that at 10 samples per avatar service and
//! 9 per frame service; raise `max_subscribers` deliberately.

use super::layout::PayloadKind;

/// Service sizing shared by publishers and subscribers. Both sides must use the same values:
/// the first to open a service fixes them, and a later opener asking for more is refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShmOptions {
    /// Subscribers one service accepts (each one reserves buffer + borrowed samples).
    pub max_subscribers: usize,
    /// Publishers one service accepts (one producer per stream is the design).
    pub max_publishers: usize,
    /// iceoryx2 nodes (processes) that may open one service.
    pub max_nodes: usize,
    /// Samples queued per subscriber; when full the oldest is overwritten (latest wins).
    pub subscriber_buffer: usize,
    /// Samples one subscriber may hold at once.
    pub subscriber_max_borrowed: usize,
    /// Last avatars replayed to a subscriber that connects late.
    pub avatar_history: usize,
    /// Last frames replayed to a subscriber that connects late.
    pub frame_history: usize,
    /// Samples the publisher may have loaned at once.
    pub max_loaned: usize,
    /// Initial payload capacity in bytes; larger payloads grow the segment by powers of two.
    pub initial_capacity: usize,
}

impl Default for ShmOptions {
    fn default() -> Self {
        Self {
            max_subscribers: 4,
            max_publishers: 1,
            max_nodes: 8,
            subscriber_buffer: 1,
            subscriber_max_borrowed: 1,
            avatar_history: 1,
            frame_history: 0,
            max_loaned: 1,
            initial_capacity: 1 << 20,
        }
    }
}

impl ShmOptions {
    /// History depth of services carrying `kind`.
    pub fn history(&self, kind: PayloadKind) -> usize {
        match kind {
            PayloadKind::Avatar => self.avatar_history,
            PayloadKind::Frame => self.frame_history,
        }
    }

    /// Samples one publisher of `kind` preallocates (iceoryx2's worst-case formula).
    pub fn preallocated_samples(&self, kind: PayloadKind) -> usize {
        self.max_subscribers * (self.subscriber_buffer + self.subscriber_max_borrowed)
            + self.history(kind)
            + self.max_loaned
    }
}

/// Errors in person or camera names.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("{what} name {name:?}: must be 1..={max} bytes of [A-Za-z0-9_-]")]
pub struct ServiceNameError {
    /// `person` or `camera`.
    pub what: &'static str,
    /// The rejected name.
    pub name: String,
    /// Longest allowed name.
    pub max: usize,
}

fn check(what: &'static str, name: &str, max: usize) -> Result<(), ServiceNameError> {
    let ok = !name.is_empty()
        && name.len() <= max
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
    if ok {
        Ok(())
    } else {
        Err(ServiceNameError {
            what,
            name: name.to_owned(),
            max,
        })
    }
}

/// `lhmpp/<person>/avatar`.
pub fn avatar_service(person: &str) -> Result<String, ServiceNameError> {
    check("person", person, 32)?;
    Ok(format!("lhmpp/{person}/avatar"))
}

/// `lhmpp/<person>/frame/<camera>`.
pub fn frame_service(person: &str, camera: &str) -> Result<String, ServiceNameError> {
    check("person", person, 32)?;
    check("camera", camera, 64)?;
    Ok(format!("lhmpp/{person}/frame/{camera}"))
}

/// `lhmpp/<person>/events`: the event service every stream of one person notifies.
pub fn event_service(person: &str) -> Result<String, ServiceNameError> {
    check("person", person, 32)?;
    Ok(format!("lhmpp/{person}/events"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn service_names_follow_the_documented_scheme() {
        assert_eq!(avatar_service("p1").unwrap(), "lhmpp/p1/avatar");
        assert_eq!(
            frame_service("p1", "cam_0").unwrap(),
            "lhmpp/p1/frame/cam_0"
        );
        assert_eq!(event_service("p1").unwrap(), "lhmpp/p1/events");
    }

    #[test]
    fn names_with_separators_are_refused() {
        assert_eq!(frame_service("p1", "a/b").unwrap_err().what, "camera");
        assert!(avatar_service("").is_err());
    }

    #[test]
    fn default_sizing_reserves_ten_avatar_and_nine_frame_samples() {
        let o = ShmOptions::default();
        assert_eq!(o.preallocated_samples(PayloadKind::Avatar), 10);
        assert_eq!(o.preallocated_samples(PayloadKind::Frame), 9);
    }
}
