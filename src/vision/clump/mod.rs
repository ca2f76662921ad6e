//! Stage 5b: regions the silhouette alone cannot explain: touching and overlapping parts, and a
//! single part whose outline the coarse stage got partly wrong (thin arms closed over, glare).
//!
//! A region's outline is the union of pieces of its parts' outlines. Each template votes for its
//! own poses from those pieces (a generalised Hough transform: a pair of outline points, one on
//! the region and one on the template, with their normals, fixes the rotation and the centroid),
//! so a part is found from the part of its outline that shows, wherever the rest is. Each
//! hypothesis is then refined by the same point-to-line ICP as a separate part and *verified
//! against the image*: every point of the template's outline at that pose must be explained,
//! either by the region's outline or by an edge across the outline's normal inside the region
//! (where a part lies on another, or where the coarse outline bridged a gap). Which of two
//! overlapping parts lies on top follows from the same evidence: the upper part's outline runs on
//! across the lower one, the lower one's outline disappears under the upper.
//!
//! The decisions (accept, `covered`, `touching/overlapping`) are the estimator's; this module
//! only finds and measures.

mod found;
mod layer;
mod leftover;
mod mask;
mod verify;
mod vote;

pub use found::{Explained, Found, MIN_SUPPORT, Region};
pub use vote::GLANCE_FROM;

use opencv::core::{self, Mat};

use super::geometry::Similarity;
use super::shape::{MODEL_VOTE_STRIDE, oriented_points};
use super::template::Library;
use super::workers::each;
use verify::Look;
use vote::Vote;

/// Finds and verifies the parts in a region. `tolerance(entry)` is the outline tolerance of that
/// template at this frame's noise, as the single-part path uses it. With more than
/// [`GLANCE_FROM`] templates and `glance`, the vote glances first (see `vote`); without, every
/// template votes in full (what tests hold the glance's decisions against).
pub fn explain(lib: &Library, region: &Region<'_>, tolerance: impl Fn(usize) -> f64 + Sync, min_leftover: f64, glance: bool) -> Explained {
    let scene = oriented_points(region.outline);
    if scene.len() < 8 {
        return Explained::default();
    }
    let mut vote = Vote::new(lib, region.outline, glance);
    let hyps = vote.hypotheses(&scene, 1.0, region.pool);
    let look = Look::new(lib, region, &tolerance);
    let (mut found, mut masks) = (Vec::new(), Vec::new());
    take(&look, region, hyps, &mut found, &mut masks);
    // A part whose outline shows less than its neighbour's may not make the first vote's
    // strongest peaks at all: the neighbour's outline votes for that neighbour again from every
    // face and type alike. What is left votes once more on its own, while it is long enough to
    // be most of a part's outline. Then, should some still be left, at a scale 5 % either side:
    // the vote at the template's scale smears the centroid's votes of a part more than about 4 %
    // larger or smaller (a 370 px radius moves 15 px, over a cell) and loses its peak, where the
    // registration would pull the scale in.
    let shortest = lib.entries.iter().map(|e| e.shape.vote.len() * MODEL_VOTE_STRIDE).min().unwrap_or(usize::MAX);
    for scale in [1.0, 0.95, 1.05] {
        if scale == 1.0 && found.is_empty() {
            continue; // the same vote again
        }
        let rest = mask::unexplained(&scene, &found, &masks, region);
        if 2 * rest.len() < shortest {
            break;
        }
        let hyps = vote.hypotheses(&rest, scale, region.pool);
        take(&look, region, hyps, &mut found, &mut masks);
    }
    let (mut found, mut masks, keep, mut rivals) = one_per_part(lib, found, masks);
    rivals.extend(look_alikes(&look, region, &mut found, &mut masks, &keep));
    layer::order(lib, region, &look.edge, &mut found, &masks, &keep, &rivals);
    let kept: Vec<&Mat> = keep.iter().map(|&i| &masks[i]).collect();
    let leftover = leftover::pieces(region, &kept, min_leftover).unwrap_or_default();
    Explained { parts: renumbered(&found, &keep), leftover, vote_ms: vote.ms }
}

/// Looks at each hypothesis in turn: a part found joins `found`, and its filled outline at its
/// pose `masks`, made once (the second vote's look at what is left and the overlap tests read
/// the same masks). A hypothesis that is a part found before it is passed over. On the region's
/// pool the looks run side by side, each as far as it would alone, and are then taken in the
/// hypotheses' order, so that the same parts are found as one by one (a look at one that turns
/// out to be found by an earlier hypothesis of the same round is the price).
fn take(look: &Look<'_>, region: &Region<'_>, hyps: Vec<(usize, Similarity, u32)>, found: &mut Vec<Found>, masks: &mut Vec<Mat>) {
    let mut keep = |ei: usize, init: &Similarity, part: Option<Found>, found: &mut Vec<Found>| {
        if let Some(part) = part.filter(|_| !verify::already_found(found, ei, init)) {
            masks.push(mask::mask_of(look.lib, &part, region.blob, region.coarse.factor).unwrap_or_default());
            found.push(part);
        }
    };
    // The strongest by share of votes are looked at, but one whose aimed pose the image
    // already rules out (what `Look::at`'s first cheap look would end) gives its place to the
    // best supported of the rest (see `vote::CANDIDATES`), which is aimed only then.
    let aim = |hyps: &[(usize, Similarity, u32)]| -> Vec<(usize, Similarity, f64)> {
        each(region.pool, hyps, |&(ei, init, _)| {
            let (pose, support) = look.aim(ei, init);
            (ei, pose, support)
        })
        .into_iter()
        .filter(|a| a.2 >= verify::LOOK_FROM)
        .collect()
    };
    let first = vote::MAX_HYPOTHESES.min(hyps.len());
    let mut looked = aim(&hyps[..first]);
    if looked.len() < vote::MAX_HYPOTHESES && first < hyps.len() {
        let mut rest = aim(&hyps[first..]);
        rest.sort_by(|a, b| b.2.total_cmp(&a.2));
        let room = vote::MAX_HYPOTHESES - looked.len();
        looked.extend(rest.into_iter().take(room));
    }
    if region.pool.is_none() {
        for (ei, init, _) in looked {
            if !verify::already_found(found, ei, &init) {
                let part = look.at(ei, init);
                keep(ei, &init, part, found);
            }
        }
        return;
    }
    let fresh: Vec<(usize, Similarity)> =
        looked.into_iter().filter(|(ei, init, _)| !verify::already_found(found, *ei, init)).map(|(ei, init, _)| (ei, init)).collect();
    let parts = each(region.pool, &fresh, |&(ei, init)| look.at(ei, init));
    for ((ei, init), part) in fresh.into_iter().zip(parts) {
        keep(ei, &init, part, found);
    }
}

/// One physical part, several explanations (the same template from two peaks, another face or
/// type): the best stays, each other type or face is one of its rivals (best supported first).
/// Returns every explanation and its mask, best supported first, the indices of those kept, and
/// the rivals as (index of the part kept, index of the rival).
#[allow(clippy::type_complexity)]
fn one_per_part(lib: &Library, found: Vec<Found>, masks: Vec<Mat>) -> (Vec<Found>, Vec<Mat>, Vec<usize>, Vec<(usize, usize)>) {
    let mut by_support: Vec<(Found, Mat)> = found.into_iter().zip(masks).collect();
    by_support.sort_by(|a, b| b.0.support.total_cmp(&a.0.support));
    let (mut found, masks): (Vec<Found>, Vec<Mat>) = by_support.into_iter().unzip();
    let areas: Vec<f64> = masks.iter().map(|m| core::count_non_zero(m).unwrap_or(0) as f64).collect();
    let (mut keep, mut rivals): (Vec<usize>, Vec<(usize, usize)>) = (Vec::new(), Vec::new());
    for i in 0..found.len() {
        let same = keep.iter().copied().find(|&k| {
            let inter = mask::overlap(&masks[i], &masks[k]);
            inter > 0.5 * areas[i].min(areas[k]).max(1.0)
        });
        match same {
            None => keep.push(i),
            Some(k) => {
                let (a, b) = (&lib.entries[found[k].entry].template, &lib.entries[found[i].entry].template);
                let (entry, reg, support) = (found[i].entry, found[i].reg, found[i].support);
                if (a.type_name != b.type_name || a.face != b.face) && found[k].rivals.iter().all(|r| r.0 != entry) {
                    found[k].rivals.push((entry, reg, support));
                    rivals.push((k, i));
                }
            }
        }
    }
    (found, masks, keep, rivals)
}

/// A kept part is held against its look-alikes (`Library::alike`: another face of one outline,
/// a revision sibling; with a catalogue the glance runs on, `Library::resembles`: a shape of
/// another type as well): each is looked at at the part's pose, and the best supported that the
/// image explains joins its rivals, to be told apart where the two differ; and when it is
/// better supported than the part itself, it is the part, the part its first rival (and its
/// mask is the part's). Any other that follows the material more closely than the part joins
/// them too: on the unseen catalogue of seed 5 a face down lying on another part was found as
/// its face up turned 11 degrees (its round body fits either way), while a shape of another
/// type, no closer, was a little better supported than the right face.
/// Each look joins `found` (with its mask), so that which part lies on top carries over to it
/// (`layer::order`); returned as (part, look) pairs beside `one_per_part`'s.
/// The vote ranks hypotheses by their share of votes and keeps a few, so a sibling explaining
/// the same material as well may never be looked at; a part would then be accepted without
/// ever being compared with the type it may be. Which of two look-alikes the vote happens to
/// reach first must not decide which one is named: the one the image explains better is.
fn look_alikes(look: &Look<'_>, region: &Region<'_>, found: &mut Vec<Found>, masks: &mut Vec<Mat>, keep: &[usize]) -> Vec<(usize, usize)> {
    // The shapes the glance cannot tell apart are looked at where it runs (more than
    // GLANCE_FROM templates; tests' full vote of the same catalogue too); below, every template
    // votes in full and its siblings are enough.
    let lib = look.lib;
    let near = if lib.entries.len() > GLANCE_FROM { &lib.resembles } else { &lib.alike };
    let todo: Vec<usize> = keep.iter().copied().filter(|&k| !near[found[k].entry].is_empty()).collect();
    let looks = each(region.pool, &todo, |&k| {
        let f = &found[k];
        let pose = f.reg.pose;
        let mut looks: Vec<Found> = near[f.entry]
            .iter()
            .filter_map(|&(j, rel)| {
                let init = Similarity {
                    from: rel.from,
                    to: pose.apply(rel.to),
                    angle_rad: pose.angle_rad + rel.angle_rad,
                    scale: pose.scale * rel.scale,
                };
                look.at(j, look.aim(j, init).0)
            })
            .collect();
        // Best supported first (stable: nearest look-alike first among equals).
        looks.sort_by(|a, b| b.support.total_cmp(&a.support));
        looks
    });
    let mut pairs = Vec::new();
    for (k, looks) in todo.into_iter().zip(looks) {
        for (n, mut r) in looks.into_iter().enumerate() {
            // Beyond the best supported, a look-alike joins only where it follows the material
            // more closely than the part: one less supported and looser says nothing more.
            if n > 0 && r.reg.rms >= found[k].reg.rms {
                continue;
            }
            // The look-alike's own look replaces whatever the search found of it.
            found[k].rivals.retain(|o| o.0 != r.entry);
            let mask = mask::mask_of(look.lib, &r, region.blob, region.coarse.factor).unwrap_or_default();
            if n == 0 && r.support > found[k].support {
                let part = &mut found[k];
                r.rivals = std::iter::once((part.entry, part.reg, part.support)).chain(part.rivals.drain(..)).collect();
                (r.under, r.order_unclear) = (part.under, part.order_unclear);
                let was = std::mem::replace(part, r);
                let was_mask = std::mem::replace(&mut masks[k], mask);
                found.push(was);
                masks.push(was_mask);
            } else {
                let list = &mut found[k].rivals;
                let at = list.iter().position(|o| o.2 < r.support).unwrap_or(list.len());
                list.insert(at, (r.entry, r.reg, r.support));
                found.push(r);
                masks.push(mask);
            }
            pairs.push((k, found.len() - 1));
        }
    }
    pairs
}

/// The kept parts, with `under` renumbered from all explanations to the kept ones.
fn renumbered(found: &[Found], keep: &[usize]) -> Vec<Found> {
    let index_of: Vec<Option<usize>> = (0..found.len()).map(|i| keep.iter().position(|&k| k == i)).collect();
    keep.iter()
        .map(|&i| {
            let mut f = found[i].clone();
            f.under = f.under.and_then(|k| index_of[k]);
            f
        })
        .collect()
}
