//! Each tracked person's avatar scored against their own true person (`lhmpp eval-crowd`).
//!
//! A crowd scene's people ([`crate::synth::crowd`]) are known exactly, so each has held-out
//! views that no camera of the scene took: the person alone, unlit (albedo), in the rest pose,
//! seen from cameras on a ring around them. Every avatar the node made from the scene is
//! rendered in its canonical (rest) pose from the same cameras and scored against every true
//! person's views. Each person's avatar is the one built mostly from their views ([`own_avatars`]:
//! the tracker replayed on the bag says whose views each id got); [`pair_avatars`] pairs them
//! one to one, best PSNR first, instead, as a check of the scores alone. The same
//! scores of the avatar the node makes from the same scene with only that person in it
//! ([`crate::synth::crowd::CrowdOptions::only`]) are the single-person reference.

use super::metrics::{mask_iou, psnr, ssim, ImageRef};
use crate::body::Pose;
use crate::splat::{render, Camera, Gaussians, RenderOptions};
use crate::synth::capture::render_dressed_views;
use crate::synth::dressed::DressedPerson;
use crate::synth::person::SynthError;
use crate::synth::stream::ring_cameras;
use glam::Vec3;
use std::collections::BTreeMap;

/// One held-out view of a true person: the camera and what it shows.
pub struct TruthView {
    /// The camera.
    pub camera: Camera,
    /// RGB in `[0, 1]` on white, row-major.
    pub rgb: Vec<f32>,
    /// Coverage (alpha) of the person.
    pub mask: Vec<f32>,
}

/// Scores of one avatar against one true person, means over the held-out views.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct AvatarScore {
    /// PSNR, dB.
    pub psnr: f64,
    /// SSIM.
    pub ssim: f64,
    /// Mask IoU (render alpha ≥ ½ against the true coverage ≥ ½).
    pub iou: f64,
}

/// `views` held-out views of `person` (`size`×`size` pixels, a ring of cameras starting
/// 45° off their front): unlit, in the rest pose, on white.
pub fn person_truth(
    person: &DressedPerson,
    views: usize,
    size: u32,
) -> Result<Vec<TruthView>, SynthError> {
    let mut cameras = ring_cameras(2 * views, size, size, person.template.height());
    // every other camera of a ring twice as dense: the ring turned by half a step
    cameras = cameras.into_iter().skip(1).step_by(2).collect();
    let rendered = render_dressed_views(person, &Pose::identity(), &cameras, false, 0)?;
    Ok(rendered
        .into_iter()
        .map(|v| TruthView {
            camera: v.rig.camera,
            rgb: v.output.rgb.iter().map(|x| x.clamp(0.0, 1.0)).collect(),
            mask: v.output.alpha.clone(),
        })
        .collect())
}

/// Renders canonical (rest-pose) Gaussians from each truth view's camera on white and scores
/// them against it.
pub fn score_avatar(canonical: &Gaussians, truth: &[TruthView]) -> AvatarScore {
    let options = RenderOptions {
        background: Vec3::ONE,
        ..RenderOptions::default()
    };
    let mut sum = AvatarScore::default();
    for view in truth {
        let out = render(canonical, &view.camera, &options);
        let rgb: Vec<f32> = out.rgb.iter().map(|x| x.clamp(0.0, 1.0)).collect();
        let (w, h) = (out.width as usize, out.height as usize);
        let (ours, theirs) = (
            ImageRef::new(&rgb, w, h, 3),
            ImageRef::new(&view.rgb, w, h, 3),
        );
        sum.psnr += psnr(ours, theirs);
        sum.ssim += ssim(ours, theirs);
        sum.iou += mask_iou(&out.alpha, &view.mask);
    }
    let n = truth.len().max(1) as f64;
    AvatarScore {
        psnr: sum.psnr / n,
        ssim: sum.ssim / n,
        iou: sum.iou / n,
    }
}

/// Pairs avatars with true persons one to one, best PSNR first: `scores[a][p]` is avatar `a`
/// against person `p`. Returns, per person, the avatar paired with it (`None` when the avatars
/// ran out).
pub fn pair_avatars(scores: &[Vec<AvatarScore>], persons: usize) -> Vec<Option<usize>> {
    let mut pairs: Vec<(usize, usize)> = (0..scores.len())
        .flat_map(|a| (0..persons).map(move |p| (a, p)))
        .collect();
    pairs.sort_by(|x, y| scores[y.0][y.1].psnr.total_cmp(&scores[x.0][x.1].psnr));
    let mut of_person = vec![None; persons];
    let mut taken = vec![false; scores.len()];
    for (a, p) in pairs {
        if !taken[a] && of_person[p].is_none() {
            taken[a] = true;
            of_person[p] = Some(a);
        }
    }
    of_person
}

/// Each true person's own avatar: among the avatars (`avatar_ids`) whose id's sightings mostly
/// cover that person (`sightings[id][person]`: how many detections given `id` covered
/// `person`), the one with the most of them. Returns, per person, the avatar's index (`None`:
/// no avatar was built mostly from them).
pub fn own_avatars(
    sightings: &BTreeMap<String, BTreeMap<usize, usize>>,
    avatar_ids: &[&str],
    persons: usize,
) -> Vec<Option<usize>> {
    let mut own: Vec<Option<(usize, usize)>> = vec![None; persons];
    for (a, id) in avatar_ids.iter().enumerate() {
        let Some(counts) = sightings.get(*id) else {
            continue;
        };
        // The majority person, the lowest index on a tie.
        let Some((&k, &n)) = counts.iter().max_by(|x, y| x.1.cmp(y.1).then(y.0.cmp(x.0))) else {
            continue;
        };
        if k < persons && own[k].is_none_or(|(_, best)| n > best) {
            own[k] = Some((a, n));
        }
    }
    own.into_iter().map(|o| o.map(|(a, _)| a)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn score(psnr: f64) -> AvatarScore {
        AvatarScore {
            psnr,
            ..AvatarScore::default()
        }
    }

    /// The best pair goes first, so a person whose best avatar was taken gets the next one,
    /// and an avatar too many pairs with nobody.
    #[test]
    fn avatars_pair_one_to_one_best_first() {
        let scores = vec![
            vec![score(20.0), score(18.0)],
            vec![score(22.0), score(15.0)],
            vec![score(12.0), score(13.0)],
        ];
        assert_eq!(pair_avatars(&scores, 2), vec![Some(1), Some(0)]);
        assert_eq!(pair_avatars(&scores[..1], 2), vec![Some(0), None]);
    }

    /// An avatar belongs to the person most of its id's views show; of two ids built mostly
    /// from one person, the one with more of their views; an id mostly of nobody's avatar and
    /// a person no id mostly shows get nothing.
    #[test]
    fn each_person_gets_the_avatar_built_mostly_from_them() {
        let counts = |pairs: &[(usize, usize)]| pairs.iter().copied().collect::<BTreeMap<_, _>>();
        let sightings: BTreeMap<String, BTreeMap<usize, usize>> = [
            ("person_0".to_string(), counts(&[(1, 30), (0, 5)])),
            ("person_1".to_string(), counts(&[(0, 20)])),
            ("person_2".to_string(), counts(&[(1, 8), (2, 3)])),
            ("person_3".to_string(), counts(&[(0, 40), (2, 10)])),
        ]
        .into();
        let avatars = ["person_0", "person_1", "person_2", "person_3"];
        assert_eq!(
            own_avatars(&sightings, &avatars, 3),
            vec![Some(3), Some(0), None]
        );
        // Without person_3's avatar, person 0's own is person_1's.
        assert_eq!(
            own_avatars(&sightings, &avatars[..3], 3),
            vec![Some(1), Some(0), None]
        );
    }

    /// A person's own Gaussians score far better against their truth than another person's.
    #[test]
    fn a_person_matches_their_own_truth() {
        let a = DressedPerson::new(700_000, 3000).unwrap();
        let b = DressedPerson::new(700_001, 3000).unwrap();
        let truth = person_truth(&a, 2, 96).unwrap();
        assert_eq!(truth.len(), 2);
        let own = score_avatar(&a.avatar.canonical, &truth);
        let other = score_avatar(&b.avatar.canonical, &truth);
        assert!(own.psnr > 40.0 && own.iou > 0.99, "{own:?}");
        assert!(other.psnr < own.psnr - 15.0, "{other:?} vs {own:?}");
    }
}
