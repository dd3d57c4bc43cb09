//! Every `.msg` definition (ours and the standard ones we embed) parses, and matches the serde
//! layout of its Rust struct field by field, so definitions and code cannot drift apart.

use lhmpp::msgs::definition::{parse_msg, ArrayKind, BaseType, Primitive};
use lhmpp::msgs::registry::{lookup, DEFINITIONS};
use lhmpp::msgs::*;
use serde_reflection::{ContainerFormat, Format, Registry, Tracer, TracerConfig};
use std::path::Path;

fn expected_element_format(base: &BaseType) -> Format {
    match base {
        BaseType::Primitive(p) => match p {
            Primitive::Bool => Format::Bool,
            Primitive::Byte | Primitive::Char | Primitive::UInt8 => Format::U8,
            Primitive::Int8 => Format::I8,
            Primitive::Int16 => Format::I16,
            Primitive::UInt16 => Format::U16,
            Primitive::Int32 => Format::I32,
            Primitive::UInt32 => Format::U32,
            Primitive::Int64 => Format::I64,
            Primitive::UInt64 => Format::U64,
            Primitive::Float32 => Format::F32,
            Primitive::Float64 => Format::F64,
        },
        BaseType::String { .. } | BaseType::WString { .. } => Format::Str,
        BaseType::Nested { name, .. } => Format::TypeName(name.clone()),
    }
}

/// Checks one definition against the traced container of its Rust struct, recursing into
/// nested types. Returns the names of the types checked.
fn check_against_layout(full_name: &str, registry: &Registry, checked: &mut Vec<String>) {
    let (full_name, text) = lookup(full_name).unwrap();
    if checked.iter().any(|c| c == full_name) {
        return;
    }
    checked.push(full_name.to_string());
    let package = full_name.split('/').next().unwrap();
    let short = full_name.rsplit('/').next().unwrap();
    let spec = parse_msg(text).unwrap_or_else(|e| panic!("{full_name}: {e}"));
    let Some(ContainerFormat::Struct(rust_fields)) = registry.get(short) else {
        panic!("{full_name}: no Rust struct named `{short}` in the traced layout");
    };
    let msg_names: Vec<&str> = spec.fields.iter().map(|f| f.name.as_str()).collect();
    let rust_names: Vec<&str> = rust_fields.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(
        msg_names, rust_names,
        "{full_name}: field names or order differ"
    );
    for (field, rust) in spec.fields.iter().zip(rust_fields) {
        let element = expected_element_format(&field.ty.base);
        let is_octet = matches!(element, Format::U8);
        let expected = match field.ty.array {
            ArrayKind::Scalar => element,
            ArrayKind::Unbounded | ArrayKind::Bounded(_) if is_octet => Format::Bytes,
            ArrayKind::Unbounded | ArrayKind::Bounded(_) => Format::Seq(Box::new(element)),
            ArrayKind::Fixed(size) => Format::TupleArray {
                content: Box::new(element),
                size,
            },
        };
        assert_eq!(
            rust.value, expected,
            "{full_name}.{}: Rust layout differs from the .msg (octet sequences must use serde_bytes)",
            field.name
        );
        if let Some(nested) = field.ty.base.nested_full_name(package) {
            check_against_layout(&nested, registry, checked);
        }
    }
}

fn trace<T: RosMessage>() -> Registry {
    let mut tracer = Tracer::new(TracerConfig::default());
    tracer.trace_simple_type::<T>().unwrap();
    tracer.registry().unwrap()
}

macro_rules! check_types {
    ($($ty:ty),* $(,)?) => {{
        let mut checked = Vec::new();
        $( check_against_layout(<$ty>::TYPE_NAME, &trace::<$ty>(), &mut checked); )*
        checked
    }};
}

#[test]
fn every_rust_message_matches_its_msg_definition_field_by_field() {
    let checked = check_types!(
        Time,
        Header,
        StdString,
        Vector3,
        Point,
        Quaternion,
        GeometryPose,
        Transform,
        TransformStamped,
        TFMessage,
        RegionOfInterest,
        Image,
        CompressedImage,
        CameraInfo,
        PointField,
        PointCloud2,
        GaussianAvatar,
        CompactAvatar,
        BodyPose,
        BodyShape,
        ReconstructionStatus,
    );
    for (name, _) in DEFINITIONS {
        assert!(checked.iter().any(|c| c == name), "{name} was not checked");
    }
}

#[test]
fn every_msg_file_in_the_repo_is_registered_and_identical() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for entry in std::fs::read_dir(root.join("msg/msg")).unwrap() {
        files.push(("lhmpp_msgs".to_string(), entry.unwrap().path()));
    }
    for package in std::fs::read_dir(root.join("src/msgs/defs")).unwrap() {
        let package = package.unwrap().path();
        if package.is_dir() {
            let name = package.file_name().unwrap().to_string_lossy().to_string();
            for entry in std::fs::read_dir(&package).unwrap() {
                files.push((name.clone(), entry.unwrap().path()));
            }
        }
    }
    assert_eq!(files.len(), DEFINITIONS.len(), "{files:?}");
    for (package, path) in files {
        let stem = path.file_stem().unwrap().to_string_lossy();
        let (_, embedded) = lookup(&format!("{package}/msg/{stem}"))
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert_eq!(std::fs::read_to_string(&path).unwrap(), embedded);
        parse_msg(embedded).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }
}

fn constants_of(text: &str) -> Vec<(String, i64)> {
    parse_msg(text)
        .unwrap()
        .constants
        .into_iter()
        .map(|c| (c.name, c.value.parse().unwrap()))
        .collect()
}

#[test]
fn rust_constants_equal_the_msg_constants() {
    let point_field: Vec<(String, i64)> = [
        ("INT8", PointField::INT8),
        ("UINT8", PointField::UINT8),
        ("INT16", PointField::INT16),
        ("UINT16", PointField::UINT16),
        ("INT32", PointField::INT32),
        ("UINT32", PointField::UINT32),
        ("FLOAT32", PointField::FLOAT32),
        ("FLOAT64", PointField::FLOAT64),
    ]
    .into_iter()
    .map(|(n, v)| (n.to_string(), v as i64))
    .collect();
    assert_eq!(constants_of(PointField::DEFINITION), point_field);
    let status: Vec<(String, i64)> = [
        ("STATE_IDLE", ReconstructionStatus::STATE_IDLE),
        ("STATE_WAITING", ReconstructionStatus::STATE_WAITING),
        (
            "STATE_RECONSTRUCTING",
            ReconstructionStatus::STATE_RECONSTRUCTING,
        ),
        ("STATE_ERROR", ReconstructionStatus::STATE_ERROR),
    ]
    .into_iter()
    .map(|(n, v)| (n.to_string(), v as i64))
    .collect();
    assert_eq!(constants_of(ReconstructionStatus::DEFINITION), status);
}

#[test]
fn our_msg_files_comment_every_field() {
    for ty in [
        "GaussianAvatar",
        "CompactAvatar",
        "BodyPose",
        "BodyShape",
        "ReconstructionStatus",
    ] {
        let (_, text) = lookup(&format!("lhmpp_msgs/{ty}")).unwrap();
        assert!(text.starts_with('#'), "{ty}: header comment first");
        let lines: Vec<&str> = text.lines().collect();
        for (i, line) in lines.iter().enumerate() {
            let t = line.trim();
            if t.is_empty() || t.starts_with('#') || t.contains('#') {
                continue;
            }
            assert!(
                i > 0 && lines[i - 1].trim().starts_with('#'),
                "{ty}: `{t}` has no comment"
            );
        }
    }
}

#[test]
fn the_interface_package_builds_every_msg_file() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("msg");
    let cmake = std::fs::read_to_string(root.join("CMakeLists.txt")).unwrap();
    let package = std::fs::read_to_string(root.join("package.xml")).unwrap();
    assert!(package.contains("<name>lhmpp_msgs</name>"));
    assert!(package.contains("<member_of_group>rosidl_interface_packages</member_of_group>"));
    for entry in std::fs::read_dir(root.join("msg")).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().to_string();
        assert!(
            cmake.contains(&format!("\"msg/{name}\"")),
            "{name} not in CMakeLists.txt"
        );
        let (_, text) = lookup(&format!("lhmpp_msgs/{}", name.trim_end_matches(".msg"))).unwrap();
        for field in parse_msg(text).unwrap().fields {
            if let BaseType::Nested {
                package: Some(p), ..
            } = &field.ty.base
            {
                assert!(
                    package.contains(&format!("<depend>{p}</depend>")),
                    "{name}: package.xml lacks <depend>{p}</depend>"
                );
            }
        }
    }
}
