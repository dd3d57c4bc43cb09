"""For tests/colcon_package.rs: is each argument a valid ROS 2 `--params-file` for the node?

Each file goes through rcl's own parser (rcl_yaml_param_parser, via
`rclpy.init(args=['--ros-args', '--params-file', FILE])`), as `ros2 run lhmpp lhmpp --ros-args
--params-file FILE` hands it to a node named `lhmpp`. Checks:
  * the parameter overrides rcl gives that node are exactly the file's parameters (nested maps
    flattened to dotted names, as ROS 2 does), with the same values;
  * a node created with `automatically_declare_parameters_from_overrides=True` declares them
    all (beside the built-in ones a node without overrides has).
One ROS 2 limitation is allowed for, and reported: an empty list (`image_topics: []`) has no
type in a ROS 2 parameter file, rcl reads it as PARAMETER_NOT_SET, and rclpy cannot declare
such a parameter. The override must still be there (lhmpp parses its parameter file itself and
reads `[]` as an empty list); the automatic declaration is then checked on the other
parameters only.

Prints one line per file, `ok FILE N parameters[ (note)]` or `fail FILE: reason`, and exits 1
if any failed.
"""

import sys

import rclpy
import rclpy.context
from rclpy.parameter import Parameter
import yaml

NODE = "lhmpp"


def flatten(prefix, value, out):
    for key, item in value.items():
        name = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(item, dict):
            flatten(name, item, out)
        else:
            out[name] = item


def plain(value):
    """rclpy's array values (lists or array.array) as lists, for comparison."""
    if isinstance(value, (str, bytes)):
        return value
    try:
        return list(value)
    except TypeError:
        return value


def builtin_parameters():
    """The parameters of a node named `lhmpp` without overrides (use_sim_time, ...)."""
    context = rclpy.context.Context()
    rclpy.init(args=[], context=context)
    try:
        node = rclpy.create_node(NODE, context=context)
        names = set(node._parameters)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    return names


def check(path, builtin):
    with open(path, encoding="utf-8") as f:
        doc = yaml.safe_load(f)
    section = doc.get(NODE, doc.get("/**")) if isinstance(doc, dict) else None
    if not isinstance(section, dict) or "ros__parameters" not in section:
        return f"no `{NODE}:` (or `/**:`) section with ros__parameters", None
    expected = {}
    flatten("", section["ros__parameters"], expected)
    if not expected:
        return "no parameters", None
    empty = sorted(k for k, v in expected.items() if v == [])
    context = rclpy.context.Context()
    try:
        rclpy.init(args=["--ros-args", "--params-file", path], context=context)
    except Exception as e:  # rcl's parser rejected the file
        return f"rcl cannot parse it: {e}", None
    try:
        node = rclpy.create_node(NODE, context=context)
        overrides = dict(node._parameter_overrides)
        node.destroy_node()
        # Automatic declaration: all overrides when there is no empty list (what
        # automatically_declare_parameters_from_overrides=True does), else one by one without
        # the untyped empty lists.
        try:
            node = rclpy.create_node(
                NODE, context=context,
                automatically_declare_parameters_from_overrides=not empty)
            for k, p in overrides.items():
                if empty and k not in empty and k not in builtin:
                    node.declare_parameter(k, p.value)
            declared = set(node._parameters) - builtin
            node.destroy_node()
        except Exception as e:
            return f"rclpy cannot declare its parameters: {e}", None
    finally:
        rclpy.shutdown(context=context)
    missing = sorted(set(expected) - set(overrides))
    if missing:
        return f"parameters rcl did not read: {missing}", None
    extra = sorted(set(overrides) - set(expected))
    if extra:
        return f"parameters the file does not have: {extra}", None
    for k in empty:
        if overrides[k].type_ != Parameter.Type.NOT_SET:
            return f"{k}: [] read as {overrides[k].type_}, expected NOT_SET", None
    differ = [f"{k}: file {expected[k]!r}, rcl {plain(overrides[k].value)!r}"
              for k in sorted(expected)
              if k not in empty and plain(expected[k]) != plain(overrides[k].value)]
    if differ:
        return "values differ: " + "; ".join(differ), None
    not_declared = sorted(set(expected) - set(empty) - declared)
    if not_declared:
        return f"not declared from the overrides: {not_declared}", None
    note = (f" (empty lists, untyped in ROS 2 so not declarable by rclpy: {', '.join(empty)})"
            if empty else "")
    return None, f"ok {path} {len(expected)} parameters{note}"


def main():
    failed = 0
    builtin = builtin_parameters()
    for path in sys.argv[1:]:
        reason, line = check(path, builtin)
        if reason is not None:
            print(f"fail {path}: {reason}", flush=True)
            failed += 1
        else:
            print(line, flush=True)
    sys.exit(1 if failed or len(sys.argv) < 2 else 0)


if __name__ == "__main__":
    main()
