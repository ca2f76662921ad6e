//! Which of two overlapping parts lies on top: the upper part's outline runs on across the lower
//! one, the lower one's disappears under the upper's surface; the parts' own interior features
//! help where the outlines lean the same way.

use opencv::core::Mat;

use super::super::geometry::{Affine, Pt};
use super::super::shape::EdgeTest;
use super::super::template::Library;
use super::found::{Found, Probe, Region};
use super::mask::{at_mask, erode};

/// For every pair of the `keep` parts that overlap (by their `masks`), which lies on top: the
/// lower one's `under` names the upper, or both are `order_unclear`. An upper part's outline
/// across a lower one then counts as seen in its support. A part that one of another part's
/// `rivals` (part kept, rival: indices into `found`) lies on is `order_unclear` as well.
pub(super) fn order(
    lib: &Library,
    region: &Region<'_>,
    edge: &EdgeTest<'_>,
    found: &mut [Found],
    masks: &[Mat],
    keep: &[usize],
    rivals: &[(usize, usize)],
) {
    let f = region.coarse.factor;
    // Which of two overlapping parts is on top: the one whose outline shows inside the other
    // (away from the other's own outline: inside its mask eroded by a decimated pixel; they
    // overlap at all where one's outline runs two decimated pixels inside the other, more than
    // the poses of touching parts are off by), where the lower one's outline runs under the
    // upper's surface and shows nothing.
    let deep: Vec<Mat> = masks.iter().map(|m| erode(m, 5).unwrap_or_default()).collect();
    let eroded: Vec<Mat> = masks.iter().map(|m| erode(m, 3).unwrap_or_default()).collect();
    let inside =
        |pts: &[Probe], mask: &Mat| -> Vec<usize> { (0..pts.len()).filter(|&j| at_mask(mask, region.blob, pts[j].at, f)).collect() };
    // Three measures of how an outline shows inside the other part: the fraction of its points
    // with an edge at all (the most telling), the mean step, and the magnitude of the mean
    // signed step (a real outline runs with one polarity, the features of the upper part that a
    // hidden outline crosses come with either). Where they do not point the same way, which
    // part lies on top stays undecided: a reject either way.
    let strength = |pts: &[Probe], idx: &[usize]| -> Steps {
        if idx.is_empty() {
            return Steps::default();
        }
        let n = idx.len() as f64;
        Steps {
            mean: idx.iter().map(|&j| pts[j].across.abs()).sum::<f64>() / n,
            signed: (idx.iter().map(|&j| pts[j].across).sum::<f64>() / n).abs(),
            shown: idx.iter().filter(|&&j| pts[j].across.abs() >= 0.4 * edge.threshold).count() as f64 / n,
        }
    };
    // The features inside a part where the other lies.
    let features = |x: &Found, zone: &Mat| -> Features {
        let t = &lib.entries[x.entry].template;
        let pose = x.reg.pose;
        let (to_frame, turn) = (pose.forward(), Affine::rotation(pose.angle_rad));
        let (mut n, mut seen) = (0usize, 0usize);
        for &(q, nq) in &t.interior {
            let at = to_frame.apply(q);
            if at_mask(zone, region.blob, at, f) {
                n += 1;
                if edge.across(at, turn.apply(nq)) >= edge.threshold {
                    seen += 1;
                }
            }
        }
        Features { count: n, shown: if n > 0 { seen as f64 / n as f64 } else { 0.0 } }
    };
    // How explanations `i` and `k` show inside each other: the points of each inside the other
    // (eroded), their steps across (measured here, where they tell something, not for every
    // point), features and whether there are enough points to tell a faint edge from none.
    let measure = |found: &mut [Found], i: usize, k: usize| {
        let (ii, kk) = (inside(&found[i].points, &eroded[k]), inside(&found[k].points, &eroded[i]));
        for (x, idx) in [(i, &ii), (k, &kk)] {
            for &j in idx {
                found[x].points[j].across(edge);
            }
        }
        let (si, sk) = (strength(&found[i].points, &ii), strength(&found[k].points, &kk));
        let (fi, fk) = (features(&found[i], &deep[k]), features(&found[k], &deep[i]));
        let enough = ii.len().min(kk.len()) >= 20;
        Pair { ii, kk, si, sk, fi, fk, enough }
    };
    let m = edge.margin;
    let mut over: Vec<Vec<usize>> = vec![Vec::new(); found.len()];
    // Of each kept part, the explanation that follows its material most closely, where a
    // look-alike (among `rivals`) does so more closely than the part.
    let closest = |found: &[Found], o: usize| {
        rivals
            .iter()
            .filter(|&&(w, r)| w == o && found[r].reg.rms < found[o].reg.rms)
            .map(|&(_, r)| r)
            .min_by(|&a, &b| found[a].reg.rms.total_cmp(&found[b].reg.rms))
    };
    let closer_pair = |found: &[Found], i: usize, k: usize| {
        let (ci, ck) = (closest(found, i).unwrap_or(i), closest(found, k).unwrap_or(k));
        ((ci, ck) != (i, k)).then_some((ci, ck))
    };
    // (part, explanation): the explanation of a part on top whose outline across the part
    // beneath counts as seen (the part itself, or a closer look-alike of it).
    let mut shown: Vec<(usize, usize)> = Vec::new();
    // Whether the first of a measured pair lies on the second (Some(true)), under it, or unclear.
    let upper = |q: &Pair| {
        if lies_on_top(q.si, q.sk, q.fi, q.fk, q.enough, m) {
            Some(true)
        } else if lies_on_top(q.sk, q.si, q.fk, q.fi, q.enough, m) {
            Some(false)
        } else {
            None
        }
    };
    for (a, &i) in keep.iter().enumerate() {
        for &k in &keep[a + 1..] {
            if inside(&found[i].points, &deep[k]).len() < 4 && inside(&found[k].points, &deep[i]).len() < 4 {
                continue; // touching at most
            }
            let p = measure(found, i, k);
            // (whether the first lies on top, the two explanations measured, how): the kept
            // ones, or where they do not tell, the closest look-alikes. One of the kept ones may
            // be the vote's first find while a look-alike follows that part's material more
            // closely (a T001 found on a T033's material, its outline running where the T033
            // shows none, across the part on top): the order the closer explanation shows is
            // the order of the material, whichever of the two is named.
            let settled = match upper(&p) {
                Some(first) => Some((first, i, k, p)),
                None => closer_pair(found, i, k)
                    .filter(|&(ci, ck)| inside(&found[ci].points, &deep[ck]).len() >= 4 || inside(&found[ck].points, &deep[ci]).len() >= 4)
                    .and_then(|(ci, ck)| {
                        let q = measure(found, ci, ck);
                        upper(&q).map(|first| (first, ci, ck, q))
                    }),
            };
            match settled {
                Some((true, xi, _, q)) => {
                    found[k].under.get_or_insert(i);
                    over[xi].extend(q.ii);
                    shown.push((i, xi));
                }
                Some((false, _, xk, q)) => {
                    found[i].under.get_or_insert(k);
                    over[xk].extend(q.kk);
                    shown.push((k, xk));
                }
                None => {
                    found[i].order_unclear = true;
                    found[k].order_unclear = true;
                }
            }
        }
    }
    // Another type or face found on one part's material that the image shows lying on a second
    // part: which of the two explanations is the part is decided later (where their templates
    // differ), and the one kept may not reach the second part at all (two lugs of a three-lug
    // flange whose third lies on a link). Something may lie on the second part: which lies on
    // top is unclear for it; should the part be that explanation, its outline across the second
    // part counts as seen, as a kept part's does.
    let mut lifted: Vec<(usize, usize)> = shown.into_iter().filter(|&(part, x)| part != x).collect();
    for &(owner, r) in rivals {
        for &k in keep {
            // Under the part itself: the rival's outline across it shows as the part's does,
            // when the rival follows the material more closely than the part (the part was
            // named first by the vote, not by the image: its own lift is no evidence against a
            // closer explanation, while a looser one gains nothing by it).
            let beneath = found[k].under == Some(owner);
            let closer = found[r].reg.rms < found[owner].reg.rms;
            if k == owner || (beneath && !closer) || inside(&found[r].points, &deep[k]).len() < 4 {
                continue;
            }
            let p = measure(found, r, k);
            if lies_on_top(p.si, p.sk, p.fi, p.fk, p.enough, m) {
                found[k].order_unclear |= !beneath;
                if beneath {
                    // Where the rival's outline runs with the part's across the lower part, it
                    // shows as the part's does; where the two differ, only what the image shows
                    // of each counts, or the part's lift alone would decide between them.
                    let near = found[r].tolerance;
                    let raised: Vec<Pt> = over[owner].iter().map(|&j| found[owner].points[j].at).collect();
                    let along: Vec<usize> =
                        p.ii.into_iter().filter(|&j| raised.iter().any(|q| (*q - found[r].points[j].at).norm() <= near)).collect();
                    over[r].extend(along);
                } else {
                    over[r].extend(p.ii);
                }
                lifted.push((owner, r));
            }
        }
    }
    // An upper part's outline across a lower part shows as well as that part's surface allows:
    // decided on top, those points count as seen.
    for i in keep.iter().copied().chain(lifted.iter().map(|&(_, r)| r)) {
        let pts = &mut found[i].points;
        for &j in &over[i] {
            pts[j].seen = true;
        }
        found[i].support = pts.iter().filter(|p| p.seen).count() as f64 / pts.len().max(1) as f64;
    }
    // The owner's list of rivals carries each one's support, best first.
    for (owner, r) in lifted {
        let (entry, support) = (found[r].entry, found[r].support);
        let list = &mut found[owner].rivals;
        for o in list.iter_mut().filter(|o| o.0 == entry) {
            o.2 = support;
        }
        list.sort_by(|a, b| b.2.total_cmp(&a.2));
    }
}

/// Two explanations measured inside each other (`order`'s `measure`): the indices of the first's
/// points inside the second and of the second's inside the first, how each outline shows there,
/// each one's features there, and whether both have enough points to tell a faint edge.
struct Pair {
    ii: Vec<usize>,
    kk: Vec<usize>,
    si: Steps,
    sk: Steps,
    fi: Features,
    fk: Features,
    enough: bool,
}

/// How one part's outline shows where it runs inside another part.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Steps {
    /// Mean magnitude of the gray-level step across it.
    mean: f64,
    /// Magnitude of its mean signed step.
    signed: f64,
    /// Fraction of its points with an edge at all (a step of 0.4 x the edge threshold).
    shown: f64,
}

/// One part's own interior features (holes' rims, pockets, bosses) where another part lies.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Features {
    /// How many interior edge points lie there.
    count: usize,
    /// The fraction of them showing with the template's polarity.
    shown: f64,
}

/// Whether the part whose outline and features show as `a` and `fa` lies on the one showing
/// `b` and `fb`; `enough`: both outlines have enough points inside the other to tell a faint
/// edge from none; `m`: the edge test's margin (gray levels). Which of two overlapping parts
/// lies on top is seen where they overlap: the upper part's outline runs on across the lower
/// one, the lower one's disappears under the upper's surface.
///
/// The most telling measure is how much of each outline shows as an edge at all; the means of
/// the steps may only not both speak against it. Two parts of one material and shade show the
/// upper one's outline faintly; it still decides where the lower one's shows nothing at all and
/// its mean step is larger by the margin. Where one part's features show almost all over the
/// other and the other's show hardly at all there, an outline that leans the same way, short of
/// deciding alone, is enough: more of it shows as an edge, and its mean step is not smaller by
/// more than the margin (means within the margin are a tie, not a vote against).
///
/// What never decides alone: features (a lower part's show through an upper part's hole),
/// hidden features (an upper part's through-hole shows the part beneath instead of the belt,
/// its rim's step reversed), the polarity of the steps (an upper part's outline over a lower
/// part of several shades changes polarity along its way).
fn lies_on_top(a: Steps, b: Steps, fa: Features, fb: Features, enough: bool, m: f64) -> bool {
    let shows = |x: Features| x.count >= FEATURES_MIN && x.shown >= FEATURES_SHOWN;
    let hidden = |x: Features| x.count < FEATURES_MIN || x.shown <= FEATURES_HIDDEN;
    let not_against = !(b.mean > a.mean + m && b.signed > a.signed + m);
    let clear = a.shown >= 0.4 && a.shown >= b.shown + 0.2 && not_against;
    let faint = enough && a.shown >= 0.15 && b.shown <= 0.05 && a.mean >= b.mean + m;
    let leans = a.shown >= b.shown + 0.1 && a.mean >= b.mean - m && not_against;
    let featured = shows(fa) && hidden(fb) && leans;
    clear || faint || featured
}

/// Interior edge points of a part over another that make its features count at all.
const FEATURES_MIN: usize = 8;
/// Fraction of them showing for the features to show (see [`lies_on_top`]).
const FEATURES_SHOWN: f64 = 0.8;
/// Fraction of them at most showing for the features to be hidden.
const FEATURES_HIDDEN: f64 = 0.2;
#[cfg(test)]
mod tests {
    use super::*;

    const M: f64 = 3.0;

    fn steps(mean: f64, signed: f64, shown: f64) -> Steps {
        Steps { mean, signed, shown }
    }

    fn features(count: usize, shown: f64) -> Features {
        Features { count, shown }
    }

    /// The upper part's outline shows as an edge over the lower part; the lower one's, under
    /// the upper's surface, hardly at all: decided both ways round, whichever is asked first.
    #[test]
    fn the_outline_that_shows_lies_on_top() {
        let (upper, lower) = (steps(30.0, 28.0, 0.8), steps(6.0, 1.0, 0.1));
        let none = Features::default();
        assert!(lies_on_top(upper, lower, none, none, true, M));
        assert!(!lies_on_top(lower, upper, none, none, true, M));
    }

    /// Features showing all over the other part, the other's hidden, and an outline that leans
    /// the same way decide even where the outlines' mean steps tie within the margin (a
    /// simulated clevis under a bracket: 9.48 against 9.56 gray levels, margin 2.96).
    #[test]
    fn features_and_a_leaning_outline_decide_on_a_tie_of_means() {
        let (upper, lower) = (steps(9.48, 7.34, 0.435), steps(9.56, 8.19, 0.278));
        assert!(lies_on_top(upper, lower, features(10, 1.0), features(0, 0.0), true, 2.96));
        assert!(!lies_on_top(lower, upper, features(0, 0.0), features(10, 1.0), true, 2.96));
        // A mean smaller by more than the margin speaks against it.
        assert!(!lies_on_top(steps(5.0, 4.0, 0.435), lower, features(10, 1.0), features(0, 0.0), true, 2.96));
    }

    /// Features alone never decide: an upper part's through-holes showing the part beneath
    /// (their rims reversed, so that its features look hidden) do not put the lower part on top
    /// (a simulated flange under a bracket: the bracket's outline decides), nor do a lower
    /// part's features seen through an upper part's hole with outlines that lean neither way.
    #[test]
    fn features_alone_never_decide() {
        let (flange, bracket) = (steps(14.5, 14.5, 0.33), steps(16.7, 3.4, 0.66));
        assert!(!lies_on_top(flange, bracket, features(0, 0.0), features(60, 0.0), true, 3.45));
        assert!(lies_on_top(bracket, flange, features(60, 0.0), features(0, 0.0), true, 3.45));
        let tie = steps(10.0, 8.0, 0.3);
        assert!(!lies_on_top(tie, tie, features(20, 1.0), features(20, 0.0), true, M));
    }

    /// Two parts of one shade: the upper outline's faint edge decides only where the lower's
    /// shows none and there are enough points to tell.
    #[test]
    fn a_faint_outline_decides_only_against_none_with_enough_points() {
        let (faint, none) = (steps(12.0, 11.0, 0.2), steps(4.0, 1.0, 0.02));
        let f = Features::default();
        assert!(lies_on_top(faint, none, f, f, true, M));
        assert!(!lies_on_top(faint, none, f, f, false, M));
        assert!(!lies_on_top(faint, steps(4.0, 1.0, 0.1), f, f, true, M));
    }
}
