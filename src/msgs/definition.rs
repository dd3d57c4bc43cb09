//! A parser for ROS 2 `.msg` definitions: field types (primitives, strings, nested types),
//! unbounded, bounded and fixed arrays, bounded strings, constants, default values, comments.
//!
//! Used to resolve dependencies when writing bag schemas and, in tests, to check that the Rust
//! structs match their definitions.

use super::MsgError;

/// A parsed `.msg` file: fields in order and constants.
#[derive(Debug, Clone, PartialEq)]
pub struct MsgSpec {
    /// Fields, in wire order.
    pub fields: Vec<FieldSpec>,
    /// Constants (`TYPE NAME = VALUE`), which are not on the wire.
    pub constants: Vec<ConstantSpec>,
}

/// One field: `TYPE NAME [DEFAULT]`.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldSpec {
    /// Field name.
    pub name: String,
    /// Field type.
    pub ty: FieldType,
    /// Default value as written, if any.
    pub default: Option<String>,
}

/// One constant: `TYPE NAME = VALUE`.
#[derive(Debug, Clone, PartialEq)]
pub struct ConstantSpec {
    /// Constant name.
    pub name: String,
    /// Constant type (a primitive or string).
    pub ty: BaseType,
    /// Value as written (for strings: the rest of the line).
    pub value: String,
}

/// A field type: a base type and how many of it.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldType {
    /// Element type.
    pub base: BaseType,
    /// Scalar or array kind.
    pub array: ArrayKind,
}

/// Scalar or array.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArrayKind {
    /// A single value.
    Scalar,
    /// `T[]`: a sequence of any length.
    Unbounded,
    /// `T[<=N]`: a sequence of at most N elements.
    Bounded(usize),
    /// `T[N]`: exactly N elements, no length on the wire.
    Fixed(usize),
}

/// Element type of a field.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BaseType {
    /// A primitive number or bool.
    Primitive(Primitive),
    /// `string` or `string<=N`.
    String {
        /// Maximum length, if bounded.
        bound: Option<usize>,
    },
    /// `wstring` or `wstring<=N`.
    WString {
        /// Maximum length, if bounded.
        bound: Option<usize>,
    },
    /// Another message type, `pkg/Type` or `Type` (same package).
    Nested {
        /// Package, when written.
        package: Option<String>,
        /// Type name.
        name: String,
    },
}

/// Primitive `.msg` types.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Primitive {
    /// `bool`.
    Bool,
    /// `byte` (an octet).
    Byte,
    /// `char` (an octet).
    Char,
    /// `int8`.
    Int8,
    /// `uint8`.
    UInt8,
    /// `int16`.
    Int16,
    /// `uint16`.
    UInt16,
    /// `int32`.
    Int32,
    /// `uint32`.
    UInt32,
    /// `int64`.
    Int64,
    /// `uint64`.
    UInt64,
    /// `float32`.
    Float32,
    /// `float64`.
    Float64,
}

impl Primitive {
    /// The primitive named `name` in a `.msg` file.
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "bool" => Self::Bool,
            "byte" => Self::Byte,
            "char" => Self::Char,
            "int8" => Self::Int8,
            "uint8" => Self::UInt8,
            "int16" => Self::Int16,
            "uint16" => Self::UInt16,
            "int32" => Self::Int32,
            "uint32" => Self::UInt32,
            "int64" => Self::Int64,
            "uint64" => Self::UInt64,
            "float32" => Self::Float32,
            "float64" => Self::Float64,
            _ => return None,
        })
    }
}

impl BaseType {
    /// Full type name `pkg/msg/Type` of a nested type, resolving a bare name against the
    /// package of the definition it appears in; `None` for primitives and strings.
    pub fn nested_full_name(&self, current_package: &str) -> Option<String> {
        match self {
            BaseType::Nested { package, name } => Some(format!(
                "{}/msg/{name}",
                package.as_deref().unwrap_or(current_package)
            )),
            _ => None,
        }
    }
}

/// Parses a `.msg` definition.
pub fn parse_msg(text: &str) -> Result<MsgSpec, MsgError> {
    let mut spec = MsgSpec {
        fields: Vec::new(),
        constants: Vec::new(),
    };
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let err = |message: String| MsgError::Definition { line, message };
        let trimmed = raw.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let (type_token, rest) = trimmed
            .split_once(char::is_whitespace)
            .ok_or_else(|| err(format!("`{trimmed}` has a type but no name")))?;
        let rest = rest.trim_start();
        let ty = parse_field_type(type_token).map_err(err)?;
        let comment_at = rest.find('#');
        let equals_at = rest.find('=');
        let is_constant = match (equals_at, comment_at) {
            (Some(e), Some(c)) => e < c,
            (Some(_), None) => true,
            _ => false,
        };
        if is_constant {
            let (name, value) = rest.split_once('=').expect("found above");
            let name = name.trim();
            check_name(name).map_err(err)?;
            if ty.array != ArrayKind::Scalar || matches!(ty.base, BaseType::Nested { .. }) {
                return Err(err(format!(
                    "constant `{name}` must have a primitive or string type"
                )));
            }
            let value = match ty.base {
                BaseType::String { .. } | BaseType::WString { .. } => value.trim().to_string(),
                _ => strip_comment(value).trim().to_string(),
            };
            if value.is_empty() {
                return Err(err(format!("constant `{name}` has no value")));
            }
            spec.constants.push(ConstantSpec {
                name: name.to_string(),
                ty: ty.base,
                value,
            });
        } else {
            let rest = strip_comment(rest).trim();
            let (name, default) = match rest.split_once(char::is_whitespace) {
                Some((name, default)) => (name, Some(default.trim().to_string())),
                None => (rest, None),
            };
            check_name(name).map_err(err)?;
            spec.fields.push(FieldSpec {
                name: name.to_string(),
                ty,
                default,
            });
        }
    }
    Ok(spec)
}

fn strip_comment(s: &str) -> &str {
    s.find('#').map_or(s, |at| &s[..at])
}

fn check_name(name: &str) -> Result<(), String> {
    let mut chars = name.chars();
    let first_ok = chars.next().is_some_and(|c| c.is_ascii_alphabetic());
    if first_ok && chars.all(|c| c.is_ascii_alphanumeric() || c == '_') {
        Ok(())
    } else {
        Err(format!("`{name}` is not a valid field or constant name"))
    }
}

fn parse_field_type(token: &str) -> Result<FieldType, String> {
    let (base, array) = match token.split_once('[') {
        None => (token, ArrayKind::Scalar),
        Some((base, bracket)) => {
            let inner = bracket
                .strip_suffix(']')
                .ok_or_else(|| format!("`{token}`: array bracket not closed"))?;
            let array = if inner.is_empty() {
                ArrayKind::Unbounded
            } else if let Some(bound) = inner.strip_prefix("<=") {
                ArrayKind::Bounded(parse_size(bound, token)?)
            } else {
                ArrayKind::Fixed(parse_size(inner, token)?)
            };
            (base, array)
        }
    };
    Ok(FieldType {
        base: parse_base_type(base).map_err(|e| format!("`{token}`: {e}"))?,
        array,
    })
}

fn parse_size(s: &str, token: &str) -> Result<usize, String> {
    s.parse()
        .map_err(|_| format!("`{token}`: `{s}` is not an array size"))
}

fn parse_base_type(base: &str) -> Result<BaseType, String> {
    if let Some(primitive) = Primitive::from_name(base) {
        return Ok(BaseType::Primitive(primitive));
    }
    for (keyword, wide) in [("string", false), ("wstring", true)] {
        if let Some(rest) = base.strip_prefix(keyword) {
            let bound = if rest.is_empty() {
                None
            } else if let Some(n) = rest.strip_prefix("<=") {
                Some(
                    n.parse()
                        .map_err(|_| format!("`{n}` is not a string bound"))?,
                )
            } else {
                continue;
            };
            return Ok(if wide {
                BaseType::WString { bound }
            } else {
                BaseType::String { bound }
            });
        }
    }
    let parts: Vec<&str> = base.split('/').collect();
    let (package, name) = match parts.as_slice() {
        [name] => (None, *name),
        [package, name] | [package, "msg", name] => (Some(package.to_string()), *name),
        _ => return Err(format!("`{base}` is not a type name")),
    };
    let valid = name.chars().next().is_some_and(|c| c.is_ascii_uppercase())
        && name.chars().all(|c| c.is_ascii_alphanumeric());
    if !valid {
        return Err(format!("`{base}` is not a primitive or message type name"));
    }
    Ok(BaseType::Nested {
        package,
        name: name.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_arrays_bounds_constants_defaults_and_comments() {
        let spec = parse_msg(
            "# header comment\n\
             uint8 RED = 1  # a constant\n\
             string GREETING = hello # not a comment\n\
             int32[] a\n\
             float64[9] k # fixed\n\
             geometry_msgs/Point[<=4] pts\n\
             string<=10 short\n\
             float64 w 1\n\
             Header h\n",
        )
        .unwrap();
        assert_eq!(spec.constants.len(), 2);
        assert_eq!(spec.constants[0].value, "1");
        assert_eq!(spec.constants[1].value, "hello # not a comment");
        let kinds: Vec<ArrayKind> = spec.fields.iter().map(|f| f.ty.array).collect();
        assert_eq!(
            kinds,
            vec![
                ArrayKind::Unbounded,
                ArrayKind::Fixed(9),
                ArrayKind::Bounded(4),
                ArrayKind::Scalar,
                ArrayKind::Scalar,
                ArrayKind::Scalar
            ]
        );
        assert_eq!(spec.fields[3].ty.base, BaseType::String { bound: Some(10) });
        assert_eq!(spec.fields[4].default.as_deref(), Some("1"));
        assert_eq!(
            spec.fields[2].ty.base.nested_full_name("x"),
            Some("geometry_msgs/msg/Point".into())
        );
        assert_eq!(
            spec.fields[5].ty.base.nested_full_name("std_msgs"),
            Some("std_msgs/msg/Header".into())
        );
    }

    #[test]
    fn malformed_lines_name_their_line_number() {
        for (text, line) in [
            ("int32 ok\nfloat64[ broken\n", 2),
            ("int32\n", 1),
            ("uint8 X =\n", 1),
            ("int32 1bad\n", 1),
            ("lower/case thing\n", 1),
        ] {
            match parse_msg(text) {
                Err(MsgError::Definition { line: l, .. }) => assert_eq!(l, line, "{text}"),
                other => panic!("{text:?} gave {other:?}"),
            }
        }
    }
}
