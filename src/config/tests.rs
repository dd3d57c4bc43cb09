//! Loading, overrides and validation of parameter files.

use super::*;

const FILE: &str = "test.yaml";

fn load(text: &str, overrides: &[&str]) -> Result<NodeConfig, ConfigError> {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    NodeConfig::from_yaml(text, Path::new(FILE), &o)
}

#[test]
fn parameter_file_layout_is_read() {
    let c = load(
        "lhmpp:\n  ros__parameters:\n    person_id: alice\n    frame_store:\n      max_views: 8\n",
        &[],
    )
    .unwrap();
    assert_eq!(c.person_id, "alice");
    assert_eq!(c.frame_store.max_views, 8);
    assert_eq!(c.model, ModelConfig::default());
}

#[test]
fn unknown_key_names_key_and_file() {
    let e = load(
        "lhmpp:\n  ros__parameters:\n    frame_store:\n      max_veiws: 8\n",
        &[],
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("max_veiws"), "{e}");
    assert!(e.contains(FILE), "{e}");
}

#[test]
fn invalid_value_names_key_and_file() {
    let e = load(
        "lhmpp:\n  ros__parameters:\n    model:\n      device: tpu\n",
        &[],
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("model.device") && e.contains(FILE), "{e}");
    let e = load(
        "lhmpp:\n  ros__parameters:\n    frame_store:\n      max_views: banana\n",
        &[],
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("max_views") && e.contains(FILE), "{e}");
}

#[test]
fn more_mask_topics_than_cameras_is_refused_naming_the_key() {
    let yaml = |masks: &str| {
        format!(
            "lhmpp:\n  ros__parameters:\n    inputs:\n      image_topics: [/a, /b]\n      mask_topics: [{masks}]\n"
        )
    };
    assert_eq!(
        load(&yaml("/a_mask, /b_mask"), &[])
            .unwrap()
            .inputs
            .mask_topics
            .len(),
        2
    );
    let e = load(&yaml("/a_mask, /b_mask, /c_mask"), &[])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("inputs.mask_topics") && e.contains("3 mask topics"),
        "{e}"
    );
}

#[test]
fn render_device_must_be_cpu_or_a_cuda_this_binary_supports() {
    let yaml =
        |d: &str| format!("lhmpp:\n  ros__parameters:\n    outputs:\n      render_device: {d}\n");
    assert_eq!(
        load(&yaml("cpu"), &[]).unwrap().outputs.render_device,
        RenderDevice::Cpu
    );
    let e = load(&yaml("vulkan"), &[]).unwrap_err().to_string();
    assert!(
        e.contains("outputs.render_device") && e.contains("vulkan"),
        "{e}"
    );
    let cuda = load(&yaml("cuda"), &[]);
    if cfg!(feature = "cuda") {
        assert_eq!(cuda.unwrap().outputs.render_device, RenderDevice::Cuda);
    } else {
        let e = cuda.unwrap_err().to_string();
        assert!(
            e.contains("outputs.render_device") && e.contains("feature"),
            "{e}"
        );
    }
}

#[test]
fn every_network_preset_is_accepted_and_another_name_is_refused_naming_them() {
    let yaml = |p: &str| format!("lhmpp:\n  ros__parameters:\n    model:\n      preset: {p}\n");
    for name in crate::model::LhmppConfig::PRESETS {
        assert_eq!(load(&yaml(name), &[]).unwrap().model.preset, name);
    }
    let e = load(&yaml("lhmpp-9000m"), &[]).unwrap_err().to_string();
    assert!(
        e.contains("model.preset") && e.contains("lhmpp-9000m"),
        "{e}"
    );
    assert!(e.contains("lhmpp-700m-pixelshuffle"), "{e}");
}

#[test]
fn renderer_is_auto_gaussians_or_neural_and_a_bad_value_names_the_key() {
    let yaml = |r: &str| format!("lhmpp:\n  ros__parameters:\n    outputs:\n      renderer: {r}\n");
    assert_eq!(
        load("lhmpp:\n  ros__parameters: {}\n", &[])
            .unwrap()
            .outputs
            .renderer,
        RendererChoice::Auto
    );
    for (text, want) in [
        ("auto", RendererChoice::Auto),
        ("gaussians", RendererChoice::Gaussians),
        ("neural", RendererChoice::Neural),
    ] {
        assert_eq!(load(&yaml(text), &[]).unwrap().outputs.renderer, want);
        assert_eq!(want.as_str(), text);
    }
    let e = load(&yaml("dpt"), &[]).unwrap_err().to_string();
    assert!(
        e.contains("outputs.renderer") && e.contains("dpt") && e.contains(FILE),
        "{e}"
    );
    assert!(e.contains("neural") && e.contains("gaussians"), "{e}");
    let e = load(&yaml("gaussians"), &["outputs.renderer=Neural"])
        .unwrap_err()
        .to_string();
    assert!(e.contains("outputs.renderer"), "{e}");
}

#[test]
fn frame_qos_is_reliable_by_default_and_a_bad_value_names_the_key() {
    let yaml =
        |q: &str| format!("lhmpp:\n  ros__parameters:\n    outputs:\n      frame_qos: {q}\n");
    assert_eq!(
        load("lhmpp:\n  ros__parameters: {}\n", &[])
            .unwrap()
            .outputs
            .frame_qos,
        FrameQos::Reliable
    );
    for (text, want) in [
        ("reliable", FrameQos::Reliable),
        ("best_effort", FrameQos::BestEffort),
    ] {
        assert_eq!(load(&yaml(text), &[]).unwrap().outputs.frame_qos, want);
        assert_eq!(want.as_str(), text);
    }
    let e = load(&yaml("sensor_data"), &[]).unwrap_err().to_string();
    assert!(
        e.contains("outputs.frame_qos") && e.contains("sensor_data") && e.contains(FILE),
        "{e}"
    );
    assert!(e.contains("reliable") && e.contains("best_effort"), "{e}");
    let c = load(&yaml("reliable"), &["outputs.frame_qos=best_effort"]).unwrap();
    assert_eq!(c.outputs.frame_qos, FrameQos::BestEffort);
}

#[test]
fn disk_limits_default_to_the_latest_only_under_a_cap_and_are_validated() {
    let base = "lhmpp:\n  ros__parameters: {}\n";
    let c = load(base, &[]).unwrap();
    assert_eq!(
        (c.outputs.keep_revisions, c.outputs.max_disk_mb),
        (0, 1024.0)
    );
    let c = load(
        base,
        &["outputs.keep_revisions=5", "outputs.max_disk_mb=0.5"],
    )
    .unwrap();
    assert_eq!((c.outputs.keep_revisions, c.outputs.max_disk_mb), (5, 0.5));
    for set in ["outputs.max_disk_mb=-1", "outputs.max_disk_mb=.inf"] {
        let e = load(base, &[set]).unwrap_err().to_string();
        assert!(e.contains("outputs.max_disk_mb"), "{set}: {e}");
    }
    let e = load(base, &["outputs.keep_revisions=-1"])
        .unwrap_err()
        .to_string();
    assert!(e.contains("outputs.keep_revisions"), "{e}");
}

#[test]
fn preview_rate_and_frames_are_validated_naming_the_key() {
    let base = "lhmpp:\n  ros__parameters: {}\n";
    let c = load(base, &[]).unwrap();
    assert_eq!(c.outputs.preview_rate_hz, 1.0);
    assert_eq!(c.outputs.preview_frame, "lhmpp_avatar");
    assert_eq!(c.outputs.world_frame, "world");
    for (set, key) in [
        ("outputs.preview_rate_hz=-1", "outputs.preview_rate_hz"),
        ("outputs.preview_frame=''", "outputs.preview_frame"),
        ("outputs.world_frame=a b", "outputs.world_frame"),
        ("outputs.preview_frame=world", "outputs.preview_frame"),
    ] {
        let e = load(base, &[set]).unwrap_err().to_string();
        assert!(e.contains(key), "{set}: {e}");
    }
    assert_eq!(
        load(base, &["outputs.preview_rate_hz=0"])
            .unwrap()
            .outputs
            .preview_rate_hz,
        0.0
    );
}

#[test]
fn overrides_win_and_are_validated() {
    let text = "lhmpp:\n  ros__parameters:\n    model:\n      device: cpu\n";
    let c = load(text, &["model.num_points=8192", "outputs.dir=/tmp/x"]).unwrap();
    assert_eq!(c.model.num_points, 8192);
    assert_eq!(c.outputs.dir, "/tmp/x");
    let e = load(text, &["model.num_points=3"]).unwrap_err().to_string();
    assert!(e.contains("model.num_points"), "{e}");
    assert!(load(text, &["noequals"]).is_err());
}

#[test]
fn wrong_layout_is_explained() {
    let e = load("person_id: x\n", &[]).unwrap_err().to_string();
    assert!(e.contains("ros__parameters") && e.contains(FILE), "{e}");
}

#[test]
fn printed_config_round_trips() {
    let c = load("lhmpp:\n  ros__parameters:\n    person_id: bob\n", &[]).unwrap();
    assert_eq!(load(&c.to_param_file(), &[]).unwrap(), c);
}

#[test]
fn closed_sets_keep_their_file_names_and_a_bad_value_names_the_key() {
    let base = "lhmpp:\n  ros__parameters: {}\n";
    let c = load(base, &["model.dtype=bf16", "inputs.image_qos=reliable"]).unwrap();
    assert_eq!(c.model.dtype, Dtype::Bf16);
    assert_eq!(c.inputs.image_qos, ImageQos::Reliable);
    for (set, key, value) in [
        ("model.dtype=f64", "model.dtype", "f64"),
        (
            "inputs.image_qos=best_effort",
            "inputs.image_qos",
            "best_effort",
        ),
        ("model.device=cuda:x", "model.device", "cuda:x"),
    ] {
        let e = load(base, &[set]).unwrap_err().to_string();
        assert!(
            e.contains(key) && e.contains(value) && e.contains(FILE),
            "{e}"
        );
    }
    let printed = load(base, &[]).unwrap().to_param_file();
    for line in [
        "dtype: f32",
        "device: cpu",
        "image_qos: sensor_data",
        "render_device: cpu",
    ] {
        assert!(printed.contains(line), "{line}\n{printed}");
    }
}

#[test]
fn devices_read_and_print_as_written() {
    let base = "lhmpp:\n  ros__parameters: {}\n";
    for (text, want) in [
        ("cpu", ComputeDevice::Cpu),
        ("cuda", ComputeDevice::Cuda(None)),
        ("cuda:1", ComputeDevice::Cuda(Some(1))),
    ] {
        let c = load(base, &[&format!("model.device={text}")]).unwrap();
        assert_eq!(c.model.device, want);
        assert_eq!(c.model.device.to_string(), text);
        assert!(c.to_param_file().contains(&format!("device: {text}\n")));
    }
    assert_eq!(ComputeDevice::Cuda(None).cuda_index(), Some(0));
    let e = load(base, &["model.device=tpu"]).unwrap_err().to_string();
    assert!(e.contains("`tpu` is not cpu, cuda or cuda:N"), "{e}");
}

#[test]
fn the_people_detector_side_reaches_the_finder_and_must_be_a_multiple_of_32() {
    let text = "lhmpp:\n  ros__parameters:\n    tracking:\n      enabled: true\n";
    let c = load(text, &["perception.people_detector_side=384"]).unwrap();
    assert_eq!(c.perception.people().detector_side, 384);
    assert_eq!(
        NodeConfig::default().perception.people().detector_side,
        crate::perception::multipose::NATIVE_SIDE
    );
    for bad in ["300", "96", "2048"] {
        let e = load(text, &[&format!("perception.people_detector_side={bad}")])
            .unwrap_err()
            .to_string();
        assert!(e.contains("perception.people_detector_side"), "{bad}: {e}");
        assert!(e.contains(bad), "{bad}: {e}");
    }
}
