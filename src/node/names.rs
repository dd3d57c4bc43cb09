//! ROS 2 topic-name resolution done by the node itself (ros2-client does none): expansion of
//! relative (`image`) and private (`~/image`) names against the namespace and node name, and
//! remapping rules given as `from:=to`.
//!
//! Rules follow ROS 2: a remap rule's `from` side is expanded like any name and matched against
//! the expanded topic name; the `to` side is expanded too. The first matching rule wins.

use std::collections::BTreeMap;

/// A malformed topic name, namespace or remapping rule.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NameError {
    /// The name breaks the ROS 2 naming rules.
    #[error("invalid ROS name `{name}`: {reason}")]
    Invalid {
        /// Name given.
        name: String,
        /// Which rule it breaks.
        reason: &'static str,
    },
    /// A remapping rule is not `from:=to`.
    #[error("remapping rule `{0}` is not of the form from:=to")]
    BadRule(String),
}

/// Expands names and applies remapping for one node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NameResolver {
    namespace: String,
    node_name: String,
    /// Expanded `from` → expanded `to`.
    remaps: BTreeMap<String, String>,
}

fn validate(name: &str) -> Result<(), NameError> {
    let bad = |reason| {
        Err(NameError::Invalid {
            name: name.into(),
            reason,
        })
    };
    if name.is_empty() {
        return bad("empty");
    }
    if name.len() > 1 && name.ends_with('/') {
        return bad("ends with `/`");
    }
    if name.contains("//") {
        return bad("contains `//`");
    }
    if !name
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/' || c == '~')
    {
        return bad("only letters, digits, `_`, `/` and a leading `~` are allowed");
    }
    if name.chars().skip(1).any(|c| c == '~') {
        return bad("`~` is only allowed as the first character");
    }
    if name
        .split('/')
        .filter(|t| !t.is_empty() && *t != "~")
        .any(|t| t.starts_with(|c: char| c.is_ascii_digit()))
    {
        return bad("a name token starts with a digit");
    }
    Ok(())
}

impl NameResolver {
    /// A resolver for node `node_name` in `namespace` (`/` or `""` for none).
    pub fn new(namespace: &str, node_name: &str) -> Result<Self, NameError> {
        let ns = if namespace.is_empty() {
            "/".to_owned()
        } else if namespace.starts_with('/') {
            namespace.to_owned()
        } else {
            format!("/{namespace}")
        };
        validate(&ns)?;
        if ns.contains('~') {
            return Err(NameError::Invalid {
                name: ns,
                reason: "a namespace cannot contain `~`",
            });
        }
        validate(node_name)?;
        if node_name.contains('/') || node_name.contains('~') {
            return Err(NameError::Invalid {
                name: node_name.into(),
                reason: "a node name is a single token",
            });
        }
        Ok(Self {
            namespace: ns,
            node_name: node_name.into(),
            remaps: BTreeMap::new(),
        })
    }

    /// Adds remapping rules, each `from:=to` (as after `--remap` / `-r`).
    pub fn with_rules<'a>(
        mut self,
        rules: impl IntoIterator<Item = &'a str>,
    ) -> Result<Self, NameError> {
        for rule in rules {
            let (from, to) = rule
                .split_once(":=")
                .filter(|(f, t)| !f.is_empty() && !t.is_empty())
                .ok_or_else(|| NameError::BadRule(rule.into()))?;
            self.add_remap(from, to)?;
        }
        Ok(self)
    }

    /// Adds remappings given as a map from original to new name.
    pub fn with_map(mut self, map: &BTreeMap<String, String>) -> Result<Self, NameError> {
        for (from, to) in map {
            self.add_remap(from, to)?;
        }
        Ok(self)
    }

    fn add_remap(&mut self, from: &str, to: &str) -> Result<(), NameError> {
        let from = self.expand(from)?;
        let to = self.expand(to)?;
        self.remaps.entry(from).or_insert(to);
        Ok(())
    }

    /// The node's namespace, always absolute.
    pub fn namespace(&self) -> &str {
        &self.namespace
    }

    /// Expands a name to a fully qualified one without remapping.
    pub fn expand(&self, name: &str) -> Result<String, NameError> {
        validate(name)?;
        let ns = self.namespace.trim_end_matches('/');
        let full = if name.starts_with('/') {
            name.to_owned()
        } else if name == "~" {
            format!("{ns}/{}", self.node_name)
        } else if let Some(rest) = name.strip_prefix("~/") {
            format!("{ns}/{}/{rest}", self.node_name)
        } else if name.starts_with('~') {
            return Err(NameError::Invalid {
                name: name.into(),
                reason: "`~` must be followed by `/`",
            });
        } else {
            format!("{ns}/{name}")
        };
        Ok(full)
    }

    /// Expands and remaps a topic name: the fully qualified name the node uses on the wire.
    pub fn resolve(&self, name: &str) -> Result<String, NameError> {
        let full = self.expand(name)?;
        Ok(self.remaps.get(&full).cloned().unwrap_or(full))
    }
}

/// Splits a fully qualified name into (namespace, base name), e.g. `/a/b/c` → (`/a/b`, `c`).
pub fn split_fully_qualified(full: &str) -> (&str, &str) {
    match full.rfind('/') {
        Some(0) | None => ("/", full.trim_start_matches('/')),
        Some(i) => (&full[..i], &full[i + 1..]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn resolver() -> NameResolver {
        NameResolver::new("/robot1", "lhmpp").unwrap()
    }

    #[test]
    fn relative_private_and_absolute_names_expand() {
        let r = resolver();
        assert_eq!(r.resolve("image_raw").unwrap(), "/robot1/image_raw");
        assert_eq!(r.resolve("cam/image").unwrap(), "/robot1/cam/image");
        assert_eq!(r.resolve("~/status").unwrap(), "/robot1/lhmpp/status");
        assert_eq!(r.resolve("/abs/topic").unwrap(), "/abs/topic");
        let root = NameResolver::new("/", "lhmpp").unwrap();
        assert_eq!(root.resolve("image").unwrap(), "/image");
        assert_eq!(NameResolver::new("ns", "n").unwrap().namespace(), "/ns");
    }

    #[test]
    fn remap_rules_match_expanded_names() {
        let r = resolver()
            .with_rules(["image_raw:=/camera/color/image_raw", "/abs:=rel"])
            .unwrap();
        assert_eq!(r.resolve("image_raw").unwrap(), "/camera/color/image_raw");
        assert_eq!(
            r.resolve("/robot1/image_raw").unwrap(),
            "/camera/color/image_raw"
        );
        assert_eq!(r.resolve("/abs").unwrap(), "/robot1/rel");
        assert_eq!(r.resolve("other").unwrap(), "/robot1/other");
    }

    #[test]
    fn map_remaps_work_like_rules() {
        let map = BTreeMap::from([("~/avatar".to_string(), "/avatars/p0".to_string())]);
        let r = resolver().with_map(&map).unwrap();
        assert_eq!(r.resolve("~/avatar").unwrap(), "/avatars/p0");
    }

    #[test]
    fn malformed_names_and_rules_are_rejected_with_the_name() {
        let r = resolver();
        for bad in [
            "",
            "a//b",
            "a/",
            "has space",
            "1cam",
            "a/~b",
            "~x",
            "cam/2d",
        ] {
            let e = r.resolve(bad).unwrap_err().to_string();
            assert!(e.contains(&format!("`{bad}`")), "{bad}: {e}");
        }
        assert!(matches!(
            resolver().with_rules(["no_separator"]),
            Err(NameError::BadRule(_))
        ));
        assert!(resolver().with_rules([":=x"]).is_err());
        assert!(NameResolver::new("/ns", "a/b").is_err());
    }

    #[test]
    fn fully_qualified_names_split_into_namespace_and_base() {
        assert_eq!(split_fully_qualified("/a/b/c"), ("/a/b", "c"));
        assert_eq!(split_fully_qualified("/c"), ("/", "c"));
    }
}
