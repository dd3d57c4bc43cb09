//! Who may open the live page: loopback by default; on any other interface only holders of the
//! token given on the command line; and a WebSocket upgrade only from the page's own origin.

use std::net::SocketAddr;

/// The access rule of a live page bound to one address.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Access {
    token: Option<String>,
}

/// Why a live page may not be served as asked.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AccessError {
    /// An address other than loopback without a token.
    #[error(
        "outputs.web {addr} is not a loopback address: the live page shows people's avatars, \
         so it needs a token there (lhmpp run --web-token TOKEN; open the page with \
         ?token=TOKEN), or bind 127.0.0.1"
    )]
    TokenRequired {
        /// The address asked for.
        addr: SocketAddr,
    },
    /// An empty token.
    #[error("--web-token is empty")]
    EmptyToken,
}

impl Access {
    /// The rule for serving on `addr`: a token is required off loopback (and checked wherever
    /// one is given).
    pub fn for_address(addr: SocketAddr, token: Option<String>) -> Result<Self, AccessError> {
        if token.as_deref() == Some("") {
            return Err(AccessError::EmptyToken);
        }
        if token.is_none() && !addr.ip().is_loopback() {
            return Err(AccessError::TokenRequired { addr });
        }
        Ok(Self { token })
    }

    /// Whether a token is asked for.
    pub fn needs_token(&self) -> bool {
        self.token.is_some()
    }

    /// Whether a request presenting `presented` (the `token` query parameter) may pass; the
    /// comparison takes the same time wherever the tokens differ.
    pub fn allows(&self, presented: Option<&str>) -> bool {
        let Some(token) = &self.token else {
            return true;
        };
        let Some(presented) = presented else {
            return false;
        };
        let (a, b) = (token.as_bytes(), presented.as_bytes());
        let differences = a
            .iter()
            .zip(b)
            .fold(a.len() ^ b.len(), |d, (x, y)| d | (x ^ y) as usize);
        differences == 0
    }
}

/// Whether a WebSocket upgrade comes from the page's own origin: no `Origin` header (not a
/// browser), or an `Origin` whose `host[:port]` is the request's `Host`.
pub fn same_origin(origin: Option<&str>, host: Option<&str>) -> bool {
    let Some(origin) = origin else {
        return true;
    };
    let authority = origin
        .strip_prefix("http://")
        .or_else(|| origin.strip_prefix("https://"))
        .unwrap_or("")
        .trim_end_matches('/');
    host.is_some_and(|h| !authority.is_empty() && authority.eq_ignore_ascii_case(h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn other_interfaces_need_a_token_and_loopback_does_not() {
        let any: SocketAddr = "0.0.0.0:8765".parse().unwrap();
        let e = Access::for_address(any, None).unwrap_err().to_string();
        assert!(
            e.contains("0.0.0.0:8765") && e.contains("--web-token"),
            "{e}"
        );
        let lan: SocketAddr = "192.168.1.20:8765".parse().unwrap();
        assert!(Access::for_address(lan, None).is_err());
        let local = Access::for_address("127.0.0.1:8765".parse().unwrap(), None).unwrap();
        assert!(!local.needs_token() && local.allows(None));
        let v6 = Access::for_address("[::1]:8765".parse().unwrap(), None).unwrap();
        assert!(v6.allows(Some("anything")));
        assert_eq!(
            Access::for_address(any, Some(String::new())),
            Err(AccessError::EmptyToken)
        );
    }

    #[test]
    fn only_the_exact_token_passes() {
        let a = Access::for_address("0.0.0.0:1".parse().unwrap(), Some("s3cret".into())).unwrap();
        assert!(a.needs_token());
        assert!(a.allows(Some("s3cret")));
        for wrong in [
            None,
            Some(""),
            Some("s3cre"),
            Some("s3cret!"),
            Some("S3cret"),
        ] {
            assert!(!a.allows(wrong), "{wrong:?}");
        }
    }

    #[test]
    fn websocket_upgrades_from_another_origin_are_refused() {
        let host = Some("127.0.0.1:8765");
        assert!(same_origin(None, host), "not a browser");
        assert!(same_origin(Some("http://127.0.0.1:8765"), host));
        assert!(!same_origin(Some("http://evil.example"), host));
        assert!(!same_origin(Some("http://127.0.0.1:9999"), host));
        assert!(!same_origin(Some("null"), host));
        assert!(!same_origin(Some("http://127.0.0.1:8765"), None));
    }
}
