//! Every message definition this crate knows, by full type name, with dependency resolution
//! and the `ros2msg` schema text that rosbag2 stores in bags.

use super::definition::parse_msg;
use super::*;

/// Line of 80 `=` that separates definitions in a `ros2msg` schema.
pub const SCHEMA_SEPARATOR: &str =
    "================================================================================";

/// `(full type name, .msg text)` of every message type implemented in this crate.
pub const DEFINITIONS: &[(&str, &str)] = &[
    (Time::TYPE_NAME, Time::DEFINITION),
    (Header::TYPE_NAME, Header::DEFINITION),
    (StdString::TYPE_NAME, StdString::DEFINITION),
    (Vector3::TYPE_NAME, Vector3::DEFINITION),
    (Point::TYPE_NAME, Point::DEFINITION),
    (Quaternion::TYPE_NAME, Quaternion::DEFINITION),
    (GeometryPose::TYPE_NAME, GeometryPose::DEFINITION),
    (Transform::TYPE_NAME, Transform::DEFINITION),
    (TransformStamped::TYPE_NAME, TransformStamped::DEFINITION),
    (TFMessage::TYPE_NAME, TFMessage::DEFINITION),
    (RegionOfInterest::TYPE_NAME, RegionOfInterest::DEFINITION),
    (Image::TYPE_NAME, Image::DEFINITION),
    (CompressedImage::TYPE_NAME, CompressedImage::DEFINITION),
    (CameraInfo::TYPE_NAME, CameraInfo::DEFINITION),
    (PointField::TYPE_NAME, PointField::DEFINITION),
    (PointCloud2::TYPE_NAME, PointCloud2::DEFINITION),
    (GaussianAvatar::TYPE_NAME, GaussianAvatar::DEFINITION),
    (CompactAvatar::TYPE_NAME, CompactAvatar::DEFINITION),
    (BodyPose::TYPE_NAME, BodyPose::DEFINITION),
    (BodyShape::TYPE_NAME, BodyShape::DEFINITION),
    (
        ReconstructionStatus::TYPE_NAME,
        ReconstructionStatus::DEFINITION,
    ),
];

/// Normalises `pkg/Type` or `pkg/msg/Type` to `pkg/msg/Type`.
pub fn full_type_name(type_name: &str) -> String {
    match type_name.split('/').collect::<Vec<_>>().as_slice() {
        [package, name] => format!("{package}/msg/{name}"),
        _ => type_name.to_string(),
    }
}

/// The `(full name, .msg text)` of a known type, given as `pkg/Type` or `pkg/msg/Type`.
pub fn lookup(type_name: &str) -> Result<(&'static str, &'static str), MsgError> {
    let full = full_type_name(type_name);
    DEFINITIONS
        .iter()
        .find(|(name, _)| *name == full)
        .copied()
        .ok_or_else(|| MsgError::UnknownType(type_name.to_string()))
}

/// Full names of the types `type_name` uses, transitively, each once, in depth-first
/// first-use order (the order rosbag2 appends them in).
pub fn dependencies_of(type_name: &str) -> Result<Vec<&'static str>, MsgError> {
    let (root, _) = lookup(type_name)?;
    let mut found = Vec::new();
    visit(root, &mut found)?;
    Ok(found)
}

fn visit(type_name: &'static str, found: &mut Vec<&'static str>) -> Result<(), MsgError> {
    let (_, text) = lookup(type_name)?;
    let package = type_name.split('/').next().unwrap_or_default();
    for field in parse_msg(text)?.fields {
        if let Some(nested) = field.ty.base.nested_full_name(package) {
            let (dependency, _) = lookup(&nested)?;
            if !found.contains(&dependency) {
                found.push(dependency);
                visit(dependency, found)?;
            }
        }
    }
    Ok(())
}

/// The `ros2msg` schema data of a type as rosbag2 writes it: the type's definition, then
/// for each dependency a line of 80 `=`, a line `MSG: pkg/msg/Type` and its definition.
pub fn ros2msg_schema(type_name: &str) -> Result<String, MsgError> {
    let (_, text) = lookup(type_name)?;
    let mut schema = text.trim_end().to_string();
    schema.push('\n');
    for dependency in dependencies_of(type_name)? {
        let (_, dep_text) = lookup(dependency)?;
        schema.push_str(SCHEMA_SEPARATOR);
        schema.push_str("\nMSG: ");
        schema.push_str(dependency);
        schema.push('\n');
        schema.push_str(dep_text.trim_end());
        schema.push('\n');
    }
    Ok(schema)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_depends_on_header_then_time() {
        assert_eq!(
            Image::dependencies(),
            vec!["std_msgs/msg/Header", "builtin_interfaces/msg/Time"]
        );
    }

    #[test]
    fn schema_appends_each_dependency_once_after_a_separator() {
        let schema = ros2msg_schema("tf2_msgs/TFMessage").unwrap();
        assert!(schema.starts_with("geometry_msgs/TransformStamped[] transforms\n"));
        for dep in [
            "geometry_msgs/msg/TransformStamped",
            "std_msgs/msg/Header",
            "builtin_interfaces/msg/Time",
            "geometry_msgs/msg/Transform",
            "geometry_msgs/msg/Vector3",
            "geometry_msgs/msg/Quaternion",
        ] {
            let block = format!("{SCHEMA_SEPARATOR}\nMSG: {dep}\n");
            assert_eq!(schema.matches(&block).count(), 1, "{dep}");
        }
    }

    #[test]
    fn unknown_types_are_named_in_the_error() {
        let err = ros2msg_schema("nav_msgs/Odometry").unwrap_err();
        assert!(err.to_string().contains("nav_msgs/Odometry"));
    }
}
