//! The six terrain zones of the paper's section "Influence of Terrain Type" as procedural
//! height and albedo fields over the planar texture coordinates `(x, y)` in metres (see
//! `terrain/mod.rs` for the map from geodetic position). Each zone combines multi-scale noise
//! with the features that give real terrain its texture or its lack of it; `docs/TERRAIN.md`
//! describes them and their measured feature content.
//!
//! Heights are raw samples (the terrain interpolates them on an 8 m lattice); albedos take the
//! filter width of the caller (a mip level's texel size) and are band-limited to it.

use super::Zone;
use super::noise::{
    Cell, band, cellular, detail, fast_floor, fbm, hash2, inside, lerp, ridged, smoothstep,
    sub_seed, unit, unit16, value_noise_d,
};

/// Height bounds of each zone, m: every height is clamped into them, so a ray that crosses
/// the slab without meeting the terrain cannot meet it anywhere.
pub fn height_bounds_m(zone: Zone) -> (f64, f64) {
    match zone {
        Zone::Desert => (150.0, 1_800.0),
        Zone::Farm => (60.0, 260.0),
        Zone::Forest => (60.0, 1_050.0),
        Zone::Mix => (60.0, 260.0),
        Zone::Prairie => (0.0, 10.0),
        Zone::Urban => (0.0, 80.0),
    }
}

// Layer identifiers of the sub-seeds (stable: changing one changes that layer only).
const L_RANGE: u64 = 1;
const L_BAJADA: u64 = 2;
const L_MOUNTAIN: u64 = 3;
const L_HILLS: u64 = 4;
const L_DETAIL: u64 = 5;
const L_RIVER: u64 = 6;
const L_ROAD: u64 = 7;
const L_TEX1: u64 = 8;
const L_TEX2: u64 = 9;
const L_TEX3: u64 = 10;
const L_TREES: u64 = 11;
const L_FIELDS: u64 = 12;
const L_TOWN: u64 = 13;
const L_WOODS: u64 = 14;
const L_CLEARCUT: u64 = 15;
const L_LAKE: u64 = 16;
const L_FARMSTEAD: u64 = 17;
const L_DISTRICT: u64 = 18;
const L_FREEWAY: u64 = 19;
const L_WASH: u64 = 20;
const L_SHRUBS: u64 = 21;
const L_ISLANDS: u64 = 22;
const L_SLOUGH: u64 = 23;
const L_STRIP: u64 = 24;
const L_PONDS: u64 = 25;

/// Raw height sample of `zone` at texture coordinates `(x, y)`, m (not yet clamped).
pub fn raw_height_m(zone: Zone, seed: u64, x: f64, y: f64) -> f64 {
    let s = |l| sub_seed(seed, l);
    let h = match zone {
        Zone::Desert => {
            // Bajadas 300–800 m sloping towards the isolated ranges, which rise up to 800 m
            // above them with steep ridged flanks.
            let r = desert_range_field(seed, x, y);
            let bajada = 320.0
                + 430.0 * smoothstep(-0.55, 0.75, r)
                + 45.0 * fbm(s(L_BAJADA), x, y, 4_000.0, 3, 0.5, 0.0);
            let mask = smoothstep(0.22, 0.5, r);
            let mtn = if mask > 0.0 {
                mask * 820.0 * ridged(s(L_MOUNTAIN), x, y, 3_400.0, 6, 0.0).powf(1.4)
            } else {
                0.0
            };
            bajada + mtn
        }
        Zone::Farm => {
            let base = 150.0
                + 38.0 * fbm(s(L_HILLS), x, y, 16_000.0, 3, 0.5, 0.0)
                + 4.0 * fbm(s(L_DETAIL), x, y, 1_500.0, 3, 0.5, 0.0);
            // River valleys: the only noticeable relief.
            let d = isoline_distance_m(s(L_RIVER), x, y, 9_000.0);
            base - 14.0 * (-(d / 260.0).powi(2)).exp()
        }
        Zone::Forest => {
            // Valleys 100–300 m, summits 500–900 m, never very steep.
            let n = fbm(s(L_HILLS), x, y, 9_000.0, 5, 0.5, 0.0);
            170.0
                + 640.0 * smoothstep(-0.4, 0.75, n)
                + 45.0 * fbm(s(L_DETAIL), x, y, 900.0, 3, 0.5, 0.0)
        }
        Zone::Mix => {
            150.0 + 45.0 * mix_hills(seed, x, y) + 8.0 * fbm(s(L_DETAIL), x, y, 600.0, 3, 0.5, 0.0)
        }
        Zone::Prairie => {
            3.5 + 1.8 * fbm(s(L_HILLS), x, y, 6_000.0, 3, 0.5, 0.0)
                + 0.4 * fbm(s(L_DETAIL), x, y, 500.0, 3, 0.5, 0.0)
        }
        Zone::Urban => {
            28.0 + 18.0 * fbm(s(L_HILLS), x, y, 12_000.0, 3, 0.5, 0.0)
                + 2.0 * fbm(s(L_DETAIL), x, y, 1_000.0, 3, 0.5, 0.0)
        }
    };
    let (lo, hi) = height_bounds_m(zone);
    h.clamp(lo, hi)
}

/// Albedo of `zone` at texture coordinates `(x, y)`, band-limited to `filter_m`, in [0, 1].
pub fn albedo(zone: Zone, seed: u64, x: f64, y: f64, filter_m: f64) -> f64 {
    let a = match zone {
        Zone::Desert => desert(seed, x, y, filter_m),
        Zone::Farm => farm(seed, x, y, filter_m),
        Zone::Forest => forest(seed, x, y, filter_m),
        Zone::Mix => mix(seed, x, y, filter_m),
        Zone::Prairie => prairie(seed, x, y, filter_m),
        Zone::Urban => urban(seed, x, y, filter_m),
    };
    a.clamp(0.0, 1.0)
}

/// Low-frequency field whose high values are the desert's mountain ranges.
fn desert_range_field(seed: u64, x: f64, y: f64) -> f64 {
    fbm(sub_seed(seed, L_RANGE), x, y, 14_000.0, 3, 0.5, 0.0)
}

/// Rolling hills of the mix zone, in about [−1, 1] (also decides woods versus fields).
fn mix_hills(seed: u64, x: f64, y: f64) -> f64 {
    fbm(sub_seed(seed, L_HILLS), x, y, 3_000.0, 4, 0.5, 0.0)
}

/// Approximate distance to the zero isoline of a value-noise field of wavelength
/// `wavelength_m` (winding roads, rivers, washes): `|n| / |∇n|`, with the gradient floored so
/// that flat saddles do not make wide blobs.
fn isoline_distance_m(seed: u64, x: f64, y: f64, wavelength_m: f64) -> f64 {
    let (n, gx, gy) = value_noise_d(seed, x / wavelength_m, y / wavelength_m);
    let g = (gx * gx + gy * gy).sqrt().max(0.6) / wavelength_m;
    n.abs() / g
}

/// Trees of crown size `crown_m` covering a fraction `coverage` of the crown sites; returns
/// (mask, albedo of the trees). Crowns are lit in the middle and darker at the rim. Under a
/// filter wider than the crowns the mask fades to its mean and the albedo to the mean crown.
fn trees(
    seed: u64,
    x: f64,
    y: f64,
    crown_m: f64,
    coverage: f64,
    base: f64,
    filter_m: f64,
) -> (f64, f64) {
    let k = detail(crown_m, filter_m);
    let mean_mask = 0.62 * coverage;
    let mean_alb = base * 0.93;
    if k <= 0.0 {
        return (mean_mask, mean_alb);
    }
    let c: Cell = cellular(seed, x, y, crown_m, 0.85);
    let present = unit16(c.id, 2) < coverage;
    let r = 0.5 * crown_m * (0.8 + 0.45 * unit16(c.id, 3));
    let q = (c.d1_m / r).min(1.0);
    let alb = base * (0.78 + 0.45 * unit16(c.id, 0)) * (1.0 - 0.3 * q * q);
    let m = if present {
        inside(c.d1_m - r, filter_m)
    } else {
        0.0
    };
    (lerp(mean_mask, m, k), lerp(mean_alb, alb, k))
}

/// Closed canopy: crowns over a shadowed understorey.
fn canopy(seed: u64, x: f64, y: f64, crown_m: f64, base: f64, filter_m: f64) -> f64 {
    let (m, a) = trees(seed, x, y, crown_m, 0.97, base, filter_m);
    lerp(base * 0.38, a, m)
}

/// Signed distance to an axis-aligned box of half sizes `(hx, hy)` centred at the origin.
#[inline]
fn box_sd(dx: f64, dy: f64, hx: f64, hy: f64) -> f64 {
    let qx = dx.abs() - hx;
    let qy = dy.abs() - hy;
    let out = (qx.max(0.0).powi(2) + qy.max(0.0).powi(2)).sqrt();
    out + qx.max(qy).min(0.0)
}

/// Residential blocks in block-grid coordinates `(u, v)`: streets, sidewalks, lots with houses
/// (gabled roofs of varied albedo), driveways, yards and trees.
#[expect(
    clippy::too_many_arguments,
    reason = "block geometry: all plain numbers, named at the call"
)]
fn residential(
    seed: u64,
    u: f64,
    v: f64,
    block_l: f64,
    block_w: f64,
    street_hw: f64,
    tree_cover: f64,
    f: f64,
) -> f64 {
    let bu = fast_floor(u / block_l);
    let bv = fast_floor(v / block_w);
    let lu = u - bu * block_l;
    let lv = v - bv * block_w;
    let d_street = lu.min(block_l - lu).min(lv.min(block_w - lv));
    let hb = hash2(seed, bu as i64, bv as i64);
    let lot_w = 15.0 + 7.0 * unit16(hb, 0);
    let depth = 0.5 * block_w - street_hw;
    let row = if lv < 0.5 * block_w { 0 } else { 1 };
    let lot_i = fast_floor((lu - street_hw) / lot_w);
    let cu = street_hw + (lot_i + 0.5) * lot_w;
    let lh = hash2(
        seed ^ 0x10f5,
        bu as i64 * 256 + lot_i as i64,
        bv as i64 * 2 + row,
    );
    // Yard with trees.
    let yard = 0.22 + 0.07 * unit16(lh, 3);
    let (tm, ta) = trees(
        seed ^ 0x7ee5,
        u,
        v,
        7.0,
        tree_cover * (0.4 + 1.2 * unit16(hb, 1)),
        0.2,
        f,
    );
    let mut a = lerp(yard, ta, tm);
    let whole_lot = lot_i >= 0.0 && cu + 0.5 * lot_w <= block_l - street_hw;
    if whole_lot && depth > 10.0 {
        let hw = lot_w * (0.28 + 0.12 * unit16(lh, 0));
        let hd = (depth * (0.22 + 0.1 * unit16(lh, 1))).min(9.0);
        let setback = 5.0 + 4.0 * unit16(lh, 2);
        let cv = if row == 0 {
            street_hw + setback + hd
        } else {
            block_w - street_hw - setback - hd
        };
        // Driveway from the street to the house.
        let dv_lo = if row == 0 { street_hw } else { cv };
        let dv_hi = if row == 0 { cv } else { block_w - street_hw };
        let du = lu - (cu + hw - 1.8);
        let drive = band(du, 1.6, f)
            * inside(
                box_sd(0.0, lv - 0.5 * (dv_lo + dv_hi), 0.0, 0.5 * (dv_hi - dv_lo)),
                f,
            );
        a = lerp(a, 0.5, drive);
        let roof = 0.3 + 0.5 * unit(lh);
        // Gabled roof: the two halves are lit differently.
        let ridge = inside(lv - cv, f);
        let roof = roof * lerp(1.0, 0.78, ridge);
        a = lerp(a, roof, inside(box_sd(lu - cu, lv - cv, hw, hd), f));
        // An occasional pool behind the house.
        if unit16(lh, 3) < 0.12 {
            let pv = if row == 0 {
                cv + hd + 5.0
            } else {
                cv - hd - 5.0
            };
            a = lerp(a, 0.6, inside(box_sd(lu - cu, lv - pv, 3.0, 2.0), f));
        }
    }
    let sidewalk = band(d_street - street_hw - 1.0, 0.9, f);
    a = lerp(a, 0.55, sidewalk);
    let asphalt = 0.16 + 0.03 * unit16(hb, 2);
    lerp(a, asphalt, band(d_street, street_hw, f))
}

/// Commercial blocks: big flat roofs with rooftop units, parking lots with stall lines.
fn commercial(
    seed: u64,
    u: f64,
    v: f64,
    block_l: f64,
    block_w: f64,
    street_hw: f64,
    f: f64,
) -> f64 {
    let bu = fast_floor(u / block_l);
    let bv = fast_floor(v / block_w);
    let lu = u - bu * block_l;
    let lv = v - bv * block_w;
    let d_street = lu.min(block_l - lu).min(lv.min(block_w - lv));
    let hb = hash2(seed ^ 0xc0de, bu as i64, bv as i64);
    // Parking lot with stall lines every 2.7 m (faded out when unresolvable).
    let stripes = {
        let p = 2.7;
        let s = (lu / p).fract() * p;
        band(s.min(p - s), 0.08, f) * detail(p, f)
    };
    let mut a = lerp(0.3 + 0.05 * unit16(hb, 0), 0.7, stripes);
    // One or two buildings.
    let n = if unit16(hb, 1) < 0.5 { 1 } else { 2 };
    for k in 0..n {
        let kh = hash2(hb, k, 7);
        let half_l = 0.5 * block_l / f64::from(n as u8);
        let cu = half_l * (2 * k + 1) as f64;
        let hw = (half_l - street_hw - 8.0) * (0.55 + 0.4 * unit16(kh, 0));
        let hd = (0.5 * block_w - street_hw - 6.0) * (0.5 + 0.45 * unit16(kh, 1));
        let cv = 0.5 * block_w + (unit16(kh, 2) - 0.5) * (0.5 * block_w - street_hw - hd).max(0.0);
        let roof = 0.55 + 0.3 * unit16(kh, 3);
        let sd = box_sd(lu - cu, lv - cv, hw.max(5.0), hd.max(5.0));
        // Rooftop units: small dark squares on a 9 m grid.
        let units = {
            let (gu, gv) = ((lu - cu) / 9.0, (lv - cv) / 9.0);
            let (fu, fv) = (gu - fast_floor(gu) - 0.5, gv - fast_floor(gv) - 0.5);
            let uh = hash2(kh, fast_floor(gu) as i64, fast_floor(gv) as i64);
            if unit16(uh, 0) < 0.35 {
                inside(box_sd(fu * 9.0, fv * 9.0, 1.6, 1.6), f) * detail(3.2, f)
            } else {
                0.0
            }
        };
        let roof = lerp(roof, 0.3, units * inside(sd + 3.0, f));
        a = lerp(a, roof, inside(sd, f));
    }
    let sidewalk = band(d_street - street_hw - 1.2, 1.0, f);
    a = lerp(a, 0.58, sidewalk);
    lerp(a, 0.17, band(d_street, street_hw, f))
}

/// Small town of a rural zone: `(mask, albedo)`. Towns sit in cells of `cell_m` with
/// probability `prob`, radius `r_min…r_max`, on an axis-aligned street grid.
#[expect(
    clippy::too_many_arguments,
    reason = "town layout: all plain numbers, named at the call"
)]
fn town(
    seed: u64,
    x: f64,
    y: f64,
    cell_m: f64,
    prob: f64,
    r_min: f64,
    r_max: f64,
    f: f64,
) -> (f64, f64) {
    let s = sub_seed(seed, L_TOWN);
    let c = cellular(s, x, y, cell_m, 0.6);
    if unit16(c.id, 2) >= prob {
        return (0.0, 0.0);
    }
    let r = r_min + (r_max - r_min) * unit16(c.id, 3);
    let wobble = 0.18 * r * fbm(s ^ 0x55, x, y, 400.0, 2, 0.5, f);
    let m = inside(c.d1_m - r - wobble, f.max(8.0));
    if m <= 0.0 {
        return (0.0, 0.0);
    }
    let a = residential(s, x + 31.0, y + 17.0, 120.0, 76.0, 6.0, 0.8, f);
    (m, a)
}

fn desert(seed: u64, x: f64, y: f64, f: f64) -> f64 {
    let s = |l| sub_seed(seed, l);
    // Bright gravelly soil with large and medium scale variation.
    let soil = 0.55
        + 0.07 * fbm(s(L_TEX1), x, y, 3_000.0, 4, 0.5, f)
        + 0.05 * fbm(s(L_TEX2), x, y, 150.0, 4, 0.55, f)
        + 0.03 * fbm(s(L_TEX3), x, y, 14.0, 3, 0.5, f);
    // Mountains: darker, rough rock.
    let r = desert_range_field(seed, x, y);
    let m = smoothstep(0.2, 0.42, r);
    let rock = 0.36
        + 0.1 * fbm(s(L_MOUNTAIN) ^ 9, x, y, 500.0, 6, 0.55, f)
        + 0.12 * (ridged(s(L_MOUNTAIN) ^ 3, x, y, 90.0, 4, f) - 0.45);
    let mut a = lerp(soil, rock, m);
    // Dry washes: bright sand, lined with denser and bigger vegetation.
    let d1 = isoline_distance_m(s(L_WASH), x, y, 1_100.0);
    let d2 = isoline_distance_m(s(L_WASH) ^ 1, x, y, 2_700.0);
    let d = d1.min(d2 * 0.8);
    let wash_hw = 3.0
        + 5.0
            * smoothstep(
                0.0,
                1.0,
                0.5 + 0.5 * fbm(s(L_WASH) ^ 2, x, y, 800.0, 2, 0.5, 0.0),
            );
    a = lerp(a, 0.68, band(d, wash_hw, f) * (1.0 - m));
    let veg = (-(d - wash_hw).max(0.0) / 45.0).exp() * (1.0 - 0.7 * m);
    // Shrubs and cacti: dark dots, denser and larger along the washes.
    let (sm, sa) = trees(s(L_SHRUBS), x, y, 7.0, 0.32 + 0.55 * veg, 0.19, f);
    let (bm, ba) = trees(s(L_SHRUBS) ^ 5, x, y, 13.0, 0.6 * veg, 0.16, f);
    a = lerp(a, sa, sm * (1.0 - 0.5 * m));
    lerp(a, ba, bm)
}

fn farm(seed: u64, x: f64, y: f64, f: f64) -> f64 {
    let s = |l| sub_seed(seed, l);
    // Square-mile sections with roads on most section lines.
    const SEC: f64 = 1_609.0;
    let (su, sv) = (fast_floor(x / SEC), fast_floor(y / SEC));
    let (lx, ly) = (x - su * SEC, y - sv * SEC);
    let hs = hash2(s(L_FIELDS), su as i64, sv as i64);
    // Fields: a section is one field, two halves or four quarters; quarters may be halved.
    let split = unit16(hs, 0);
    let (fx, fy) = if split < 0.2 {
        (0, 0)
    } else if split < 0.45 {
        (i64::from(lx > 0.5 * SEC), 0)
    } else if split < 0.7 {
        (0, i64::from(ly > 0.5 * SEC))
    } else {
        let q = (i64::from(lx > 0.5 * SEC), i64::from(ly > 0.5 * SEC));
        if unit16(hs, 1) < 0.5 {
            (q.0 * 2 + i64::from((lx % (0.5 * SEC)) > 0.25 * SEC), q.1)
        } else {
            q
        }
    };
    let hf = hash2(hs, fx, fy);
    // Crops: bare soil, soy, corn, stubble, pasture: uniform plots with faint variation.
    let crop = [0.21, 0.29, 0.34, 0.47, 0.4][(unit16(hf, 0) * 5.0) as usize % 5];
    let mut a =
        crop * (0.93 + 0.14 * unit16(hf, 1)) + 0.012 * fbm(s(L_TEX1), x, y, 350.0, 3, 0.5, f);
    // Field edges: a faint grass strip on the internal boundaries.
    let e_half = (lx - 0.5 * SEC).abs().min((ly - 0.5 * SEC).abs());
    let e_q = (lx % (0.5 * SEC) - 0.25 * SEC).abs();
    let internal = match (split < 0.2, split < 0.45, split < 0.7) {
        (true, _, _) => f64::INFINITY,
        (_, true, _) => (lx - 0.5 * SEC).abs(),
        (_, _, true) => (ly - 0.5 * SEC).abs(),
        _ if unit16(hs, 1) < 0.5 => e_half.min(e_q),
        _ => e_half,
    };
    a = lerp(a, 0.3, band(internal, 1.5, f));
    // Woods: a few patches, mostly along the river.
    let d_river = isoline_distance_m(s(L_RIVER), x, y, 9_000.0);
    let woods = smoothstep(0.55, 0.6, fbm(s(L_WOODS), x, y, 2_500.0, 3, 0.5, 0.0))
        .max(1.0 - smoothstep(90.0, 140.0, d_river));
    if woods > 0.0 {
        a = lerp(a, canopy(s(L_TREES), x, y, 9.0, 0.24, f), woods);
    }
    a = lerp(a, 0.09, band(d_river, 16.0, f));
    // Farmsteads near a road: barns, silos, a house, a windbreak.
    let fh = hash2(s(L_FARMSTEAD), su as i64, sv as i64);
    if unit16(fh, 0) < 0.7 {
        let cx = 40.0 + (SEC - 80.0) * unit16(fh, 1);
        let cy = 55.0;
        let (dx, dy) = (lx - cx, ly - cy);
        if dx.abs() < 90.0 && dy.abs() < 90.0 {
            let (tm, ta) = trees(s(L_TREES) ^ 3, x, y, 8.0, 0.9, 0.2, f);
            let ring = inside(box_sd(dx, dy, 70.0, 60.0), f)
                * (1.0 - inside(box_sd(dx, dy, 52.0, 42.0), f));
            a = lerp(a, 0.36, inside(box_sd(dx, dy, 52.0, 42.0), f));
            a = lerp(a, ta, tm * ring);
            for k in 0..5 {
                let bh = hash2(fh, k, 1);
                let bx = (unit16(bh, 0) - 0.5) * 70.0;
                let by = (unit16(bh, 1) - 0.5) * 55.0;
                let (hx, hy) = (4.0 + 9.0 * unit16(bh, 2), 4.0 + 7.0 * unit16(bh, 3));
                a = lerp(
                    a,
                    0.45 + 0.35 * unit(bh),
                    inside(box_sd(dx - bx, dy - by, hx, hy), f),
                );
            }
        }
    }
    // Section-line roads.
    let line_x = hash2(s(L_ROAD), su as i64, 0);
    let line_y = hash2(s(L_ROAD), 0, sv as i64 + 1_000_000);
    let dx_road = if unit16(line_x, 0) < 0.85 {
        lx
    } else {
        f64::INFINITY
    };
    let dy_road = if unit16(line_y, 0) < 0.85 {
        ly
    } else {
        f64::INFINITY
    };
    a = lerp(a, 0.56, band(dx_road.min(dy_road), 4.0, f));
    let (tm, ta) = town(seed, x, y, 7_000.0, 0.45, 350.0, 900.0, f);
    lerp(a, ta, tm)
}

fn forest(seed: u64, x: f64, y: f64, f: f64) -> f64 {
    let s = |l| sub_seed(seed, l);
    // Stands of different species and ages.
    let stand = 0.25 + 0.06 * fbm(s(L_TEX1), x, y, 350.0, 3, 0.5, f);
    let conifer = smoothstep(0.2, 0.35, fbm(s(L_TEX2), x, y, 1_200.0, 3, 0.5, f));
    let base = lerp(stand, 0.17, conifer);
    let mut a = canopy(s(L_TREES), x, y, lerp(9.5, 6.5, conifer), base, f);
    // Clearcuts: bright rectangles with regrowth and skid trails.
    let c = cellular(s(L_CLEARCUT), x, y, 800.0, 0.7);
    if unit16(c.id, 0) < 0.22 {
        let ang = unit16(c.id, 1) * std::f64::consts::PI;
        let (sn, cs) = ang.sin_cos();
        let (u, v) = (cs * c.dx_m + sn * c.dy_m, -sn * c.dx_m + cs * c.dy_m);
        let (hu, hv) = (
            90.0 + 130.0 * unit16(c.id, 2),
            60.0 + 90.0 * unit16(c.id, 3),
        );
        let m = inside(
            box_sd(u, v, hu, hv) + 6.0 * fbm(c.id, x, y, 60.0, 2, 0.5, f),
            f,
        );
        if m > 0.0 {
            let cut = 0.38 + 0.06 * fbm(s(L_TEX3), x, y, 25.0, 3, 0.5, f);
            let (rm, ra) = trees(s(L_TREES) ^ 9, x, y, 4.5, 0.3, 0.22, f);
            let cut = lerp(
                lerp(cut, ra, rm),
                0.48,
                band((u % 40.0).abs().min(40.0 - (u % 40.0).abs()), 1.2, f),
            );
            a = lerp(a, cut, m);
        }
    }
    // Lakes in the valleys.
    let (n, gx, gy) = value_noise_d(s(L_LAKE), x / 1_800.0, y / 1_800.0);
    let g = (gx * gx + gy * gy).sqrt().max(0.6) / 1_800.0;
    a = lerp(a, 0.07, inside((n + 0.78) / g, f));
    // Winding roads.
    let d = isoline_distance_m(s(L_ROAD), x, y, 3_500.0);
    a = lerp(a, 0.5, band(d, 4.0, f));
    let (tm, ta) = town(seed, x, y, 9_000.0, 0.25, 250.0, 600.0, f);
    lerp(a, ta, tm)
}

fn mix(seed: u64, x: f64, y: f64, f: f64) -> f64 {
    let s = |l| sub_seed(seed, l);
    // Woods on the hills, fields in the valleys: about half each.
    let hills = mix_hills(seed, x, y);
    let w = smoothstep(
        -0.04,
        0.04,
        hills + 0.5 * fbm(s(L_WOODS), x, y, 900.0, 3, 0.5, 0.0),
    );
    let mut a = 0.0;
    if w < 1.0 {
        // Irregular fields with hedgerows.
        let c = cellular(s(L_FIELDS), x, y, 280.0, 0.9);
        let crop = [0.23, 0.3, 0.36, 0.45, 0.4][(unit16(c.id, 0) * 5.0) as usize % 5];
        let field =
            crop * (0.92 + 0.16 * unit16(c.id, 1)) + 0.02 * fbm(s(L_TEX1), x, y, 120.0, 3, 0.5, f);
        let edge = 0.5 * (c.d2_m - c.d1_m);
        let (hm, ha) = trees(s(L_TREES) ^ 1, x, y, 7.0, 0.85, 0.2, f);
        let hedge = band(edge, 5.0, f) * hm;
        let mut fa = lerp(field, ha, hedge);
        // Farm ponds.
        let p = cellular(s(L_PONDS), x, y, 650.0, 0.8);
        if unit16(p.id, 0) < 0.25 {
            fa = lerp(fa, 0.1, inside(p.d1_m - 18.0 - 25.0 * unit16(p.id, 1), f));
        }
        a += (1.0 - w) * fa;
    }
    if w > 0.0 {
        a += w * canopy(
            s(L_TREES),
            x,
            y,
            8.5,
            0.23 + 0.05 * fbm(s(L_TEX2), x, y, 300.0, 3, 0.5, f),
            f,
        );
    }
    let d = isoline_distance_m(s(L_ROAD), x, y, 2_600.0);
    a = lerp(a, 0.52, band(d, 4.0, f));
    let (tm, ta) = town(seed, x, y, 6_000.0, 0.35, 300.0, 700.0, f);
    lerp(a, ta, tm)
}

fn prairie(seed: u64, x: f64, y: f64, f: f64) -> f64 {
    let s = |l| sub_seed(seed, l);
    // Features elongated along the slow sheet flow (towards the south-south-west).
    let (sn, cs) = (0.35_f64).sin_cos();
    let (u, v) = (cs * x - sn * y, sn * x + cs * y);
    let (us, vs) = (u * 2.6, v);
    // Sawgrass: bright, nearly uniform.
    let mut a = 0.41
        + 0.04 * fbm(s(L_TEX1), us, vs, 2_400.0, 3, 0.5, f)
        + 0.008 * fbm(s(L_TEX2), x, y, 40.0, 3, 0.5, f);
    // Sloughs: darker wet prairie and open water, smooth edges.
    let n = fbm(s(L_SLOUGH), us, vs, 5_000.0, 3, 0.5, 0.0);
    a = lerp(
        a,
        0.25 + 0.02 * fbm(s(L_TEX3), x, y, 200.0, 2, 0.5, f),
        smoothstep(-0.3, -0.22, n),
    );
    // Tree islands: teardrops along the flow, and scattered bayheads.
    let t = fbm(s(L_ISLANDS), us, vs, 1_500.0, 4, 0.5, 0.0);
    let isl = smoothstep(0.48, 0.52, t);
    let b = cellular(s(L_ISLANDS) ^ 1, x, y, 1_100.0, 0.8);
    let bay = if unit16(b.id, 0) < 0.3 {
        inside(
            b.d1_m - 12.0 - 30.0 * unit16(b.id, 1) + 6.0 * fbm(b.id, x, y, 25.0, 2, 0.5, f),
            f,
        )
    } else {
        0.0
    };
    let island = isl.max(bay);
    if island > 0.0 {
        a = lerp(a, canopy(s(L_TREES), x, y, 7.0, 0.2, f), island);
    }
    // A few straight dirt roads with a canal alongside, and landing strips.
    const SP: f64 = 6_500.0;
    let ri = fast_floor(x / SP);
    let rh = hash2(s(L_ROAD), ri as i64, 0);
    if unit16(rh, 0) < 0.45 {
        let cx = ri * SP + SP * unit16(rh, 1);
        a = lerp(a, 0.08, band(x - cx - 14.0, 5.0, f));
        a = lerp(a, 0.6, band(x - cx, 3.0, f));
    }
    let rj = fast_floor(y / SP);
    let rh = hash2(s(L_ROAD), 0, rj as i64 + 99);
    if unit16(rh, 0) < 0.3 {
        let cy = rj * SP + SP * unit16(rh, 1);
        a = lerp(a, 0.6, band(y - cy, 3.0, f));
    }
    let c = cellular(s(L_STRIP), x, y, 15_000.0, 0.8);
    if unit16(c.id, 0) < 0.3 {
        a = lerp(a, 0.62, inside(box_sd(c.dx_m, c.dy_m, 300.0, 12.0), f));
    }
    a
}

fn urban(seed: u64, x: f64, y: f64, f: f64) -> f64 {
    let s = |l| sub_seed(seed, l);
    // Districts with their own grid orientation, block size and land use.
    let d = cellular(s(L_DISTRICT), x, y, 2_600.0, 0.8);
    let ang = if unit16(d.id, 0) < 0.6 {
        0.0
    } else {
        (unit16(d.id, 1) - 0.5) * 0.6
    };
    let (sn, cs) = ang.sin_cos();
    let (u, v) = (cs * x + sn * y, -sn * x + cs * y);
    let block_l = 190.0 + 80.0 * unit16(d.id, 2);
    let block_w = 75.0 + 25.0 * unit16(d.id, 3);
    let use_ = unit(hash2(d.id, 1, 2));
    let mut a = if use_ < 0.62 {
        residential(s(L_TOWN), u, v, block_l, block_w, 7.0, 1.0, f)
    } else if use_ < 0.9 {
        commercial(s(L_TOWN), u, v, block_l * 1.2, block_w * 1.6, 8.0, f)
    } else {
        // Parks and schools: lawns, trees, sports fields.
        let (tm, ta) = trees(s(L_TREES), x, y, 9.0, 0.45, 0.2, f);
        let lawn = 0.27 + 0.03 * fbm(s(L_TEX1), x, y, 60.0, 3, 0.5, f);
        let mut p = lerp(lawn, ta, tm);
        let bu = fast_floor(u / 300.0);
        let bv = fast_floor(v / 200.0);
        let h = hash2(d.id, bu as i64, bv as i64);
        let (lu, lv) = (u - bu * 300.0 - 150.0, v - bv * 200.0 - 100.0);
        p = lerp(
            p,
            0.6,
            inside(
                box_sd(
                    lu,
                    lv,
                    40.0 + 40.0 * unit16(h, 0),
                    25.0 + 20.0 * unit16(h, 1),
                ),
                f,
            ),
        );
        lerp(
            p,
            0.17,
            band(
                lu.abs()
                    .min(lv.abs())
                    .min(150.0 - lu.abs())
                    .min(100.0 - lv.abs()),
                7.0,
                f,
            ),
        )
    };
    // Arterials along the district borders.
    a = lerp(a, 0.19, band(0.5 * (d.d2_m - d.d1_m), 12.0, f));
    // Freeways: two families of long straight lines.
    for (k, ang) in [(0_i64, 0.21_f64), (1, 1.66)] {
        let (sn, cs) = ang.sin_cos();
        let w = cs * x + sn * y;
        const SP: f64 = 4_300.0;
        let i = fast_floor(w / SP);
        let h = hash2(s(L_FREEWAY), i as i64, k);
        if unit16(h, 0) < 0.7 {
            let c = i * SP + SP * (0.2 + 0.6 * unit16(h, 1));
            let dw = w - c;
            let fw = lerp(0.5, 0.14, band(dw.abs() - 14.0, 2.0, f));
            let fw = lerp(fw, 0.7, band(dw, 1.0, f));
            a = lerp(a, fw, band(dw, 30.0, f));
        }
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heights_stay_in_their_bounds_and_albedos_in_unit_range() {
        for zone in Zone::ALL {
            let (lo, hi) = height_bounds_m(zone);
            for k in 0..400 {
                let x = 1.2e7 + k as f64 * 733.7;
                let y = 3.9e6 - k as f64 * 411.3;
                let h = raw_height_m(zone, 1, x, y);
                assert!((lo..=hi).contains(&h), "{zone:?} {h}");
                for f in [0.0, 1.0, 4.0, 64.0] {
                    let a = albedo(zone, 1, x, y, f);
                    assert!((0.0..=1.0).contains(&a), "{zone:?} {a}");
                }
            }
        }
    }
}
