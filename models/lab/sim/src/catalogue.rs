//! The textile catalogue: 119 training textiles and 20 unseen textiles (the
//! paper's two sample books), each with a physical structure and ground-truth
//! tactile attributes derived from it.
//!
//! The catalogue is generated deterministically from a fixed seed and a table
//! of structure templates; `CATALOGUE_VERSION` changes whenever the generated
//! contents change.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Version of the built-in catalogue contents.
pub const CATALOGUE_VERSION: u32 = 1;

/// Which sample book a textile belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Book {
    /// The 119 textiles the encoder is trained on.
    Training,
    /// The 20 textiles never seen in training.
    Unseen,
}

/// Coarse structural family, used for evaluation ("weave families").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Family {
    Plain,
    Twill,
    Satin,
    Basket,
    Crepe,
    Knit,
    Rib,
    Pile,
    Terry,
    Fleece,
    Felt,
    /// Catalogue 2: loop yarn fabrics (boucle).
    Loop,
    /// Catalogue 2: tufted pile (carpet, rug).
    Tuft,
    /// Catalogue 2: soft, low-texture fabrics (blankets, pillow covers).
    Soft,
}

impl Family {
    pub const ALL: [Family; 11] = [
        Family::Plain,
        Family::Twill,
        Family::Satin,
        Family::Basket,
        Family::Crepe,
        Family::Knit,
        Family::Rib,
        Family::Pile,
        Family::Terry,
        Family::Fleece,
        Family::Felt,
    ];
    /// The families of catalogue version 2 (those of version 1 plus loop,
    /// tuft and soft).
    pub const ALL_V2: [Family; 14] = [
        Family::Plain,
        Family::Twill,
        Family::Satin,
        Family::Basket,
        Family::Crepe,
        Family::Knit,
        Family::Rib,
        Family::Pile,
        Family::Terry,
        Family::Fleece,
        Family::Felt,
        Family::Loop,
        Family::Tuft,
        Family::Soft,
    ];
}

/// The fabric's construction.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Structure {
    /// Plain (tabby) weave, 1 over 1 under.
    Plain,
    /// Ripstop: plain weave with a thicker yarn every `grid` ends and picks.
    Ripstop { grid: u8 },
    /// Twill `over`/`under` (2/1, 3/1, 2/2 ...), diagonal ribs.
    Twill { over: u8, under: u8 },
    /// Herringbone twill reversing direction every `band` ends.
    Herringbone { over: u8, under: u8, band: u8 },
    /// Satin with `harness` shafts (5 or 8): long warp floats.
    Satin { harness: u8 },
    /// Basket weave: groups of `group` yarns as one.
    Basket { group: u8 },
    /// Crepe: plain weave of high-twist yarns, pebbly surface.
    Crepe,
    /// Single jersey knit (V-shaped loops in wales).
    Jersey,
    /// Rib knit: `knit` knit wales then `purl` purl wales.
    Rib { knit: u8, purl: u8 },
    /// Cut pile (velvet, velour).
    Velvet,
    /// Corduroy: cut pile in wales `wale_mm` wide.
    Corduroy { wale_mm: f32 },
    /// Terry: uncut loops `loop_mm` across.
    Terry { loop_mm: f32 },
    /// Fleece: brushed knit, curly fibre mat.
    Fleece,
    /// Felt / nonwoven: random fibre mat.
    Felt,
    /// Catalogue 2: gauze, a coarse open plain weave (one of the few fabrics
    /// whose periodic weave shows cleanly on a real sensor).
    Gauze,
    /// Catalogue 2: long cut pile (plush, faux fur).
    Plush,
    /// Catalogue 2: boucle, a ground covered in irregular curly loops `loop_mm`
    /// across.
    Boucle { loop_mm: f32 },
    /// Catalogue 2: tufted pile in rows (carpet, rug); `tuft_mm` between rows.
    Tufted { tuft_mm: f32 },
    /// Catalogue 2: a brushed blanket (minky, fleece blanket): almost no
    /// texture under the gel.
    Blanket,
    /// Catalogue 2: a fine cover over soft padding (pillow, duvet): almost no
    /// texture under the gel.
    Padded,
}

impl Structure {
    /// The structural family.
    pub fn family(&self) -> Family {
        match self {
            Structure::Plain | Structure::Ripstop { .. } => Family::Plain,
            Structure::Twill { .. } | Structure::Herringbone { .. } => Family::Twill,
            Structure::Satin { .. } => Family::Satin,
            Structure::Basket { .. } => Family::Basket,
            Structure::Crepe => Family::Crepe,
            Structure::Jersey => Family::Knit,
            Structure::Rib { .. } => Family::Rib,
            Structure::Velvet | Structure::Corduroy { .. } => Family::Pile,
            Structure::Terry { .. } => Family::Terry,
            Structure::Fleece => Family::Fleece,
            Structure::Felt => Family::Felt,
            Structure::Gauze => Family::Plain,
            Structure::Plush => Family::Pile,
            Structure::Boucle { .. } => Family::Loop,
            Structure::Tufted { .. } => Family::Tuft,
            Structure::Blanket | Structure::Padded => Family::Soft,
        }
    }

    /// Short human name, e.g. "twill 2/1".
    pub fn label(&self) -> String {
        match self {
            Structure::Plain => "plain weave".into(),
            Structure::Ripstop { grid } => format!("ripstop ({grid})"),
            Structure::Twill { over, under } => format!("twill {over}/{under}"),
            Structure::Herringbone { over, under, band } => {
                format!("herringbone {over}/{under} x{band}")
            }
            Structure::Satin { harness } => format!("{harness}-harness satin"),
            Structure::Basket { group } => format!("basket {group}x{group}"),
            Structure::Crepe => "crepe".into(),
            Structure::Jersey => "single jersey".into(),
            Structure::Rib { knit, purl } => format!("rib {knit}x{purl}"),
            Structure::Velvet => "velvet".into(),
            Structure::Corduroy { wale_mm } => format!("corduroy {wale_mm:.1} mm wale"),
            Structure::Terry { loop_mm } => format!("terry {loop_mm:.1} mm loops"),
            Structure::Fleece => "fleece".into(),
            Structure::Felt => "felt".into(),
            Structure::Gauze => "gauze".into(),
            Structure::Plush => "plush".into(),
            Structure::Boucle { loop_mm } => format!("boucle {loop_mm:.1} mm loops"),
            Structure::Tufted { tuft_mm } => format!("tufted pile, rows {tuft_mm:.1} mm"),
            Structure::Blanket => "brushed blanket".into(),
            Structure::Padded => "padded cover".into(),
        }
    }
}

/// Fibre material; sets stiffness, hairiness and evenness of the yarns.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Fibre {
    Cotton,
    Linen,
    Wool,
    Silk,
    Polyester,
    Nylon,
    Viscose,
    Acrylic,
    Cashmere,
}

impl Fibre {
    pub const ALL: [Fibre; 9] = [
        Fibre::Cotton,
        Fibre::Linen,
        Fibre::Wool,
        Fibre::Silk,
        Fibre::Polyester,
        Fibre::Nylon,
        Fibre::Viscose,
        Fibre::Acrylic,
        Fibre::Cashmere,
    ];

    /// (bending stiffness, hairiness, irregularity, compressibility), each 0..1.
    pub fn properties(self) -> (f32, f32, f32, f32) {
        match self {
            Fibre::Cotton => (0.45, 0.35, 0.25, 0.40),
            Fibre::Linen => (0.80, 0.25, 0.70, 0.25),
            Fibre::Wool => (0.35, 0.75, 0.35, 0.70),
            Fibre::Silk => (0.20, 0.05, 0.10, 0.30),
            Fibre::Polyester => (0.60, 0.05, 0.05, 0.30),
            Fibre::Nylon => (0.50, 0.03, 0.05, 0.30),
            Fibre::Viscose => (0.25, 0.15, 0.15, 0.45),
            Fibre::Acrylic => (0.40, 0.55, 0.20, 0.65),
            Fibre::Cashmere => (0.15, 0.90, 0.30, 0.85),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Fibre::Cotton => "cotton",
            Fibre::Linen => "linen",
            Fibre::Wool => "wool",
            Fibre::Silk => "silk",
            Fibre::Polyester => "polyester",
            Fibre::Nylon => "nylon",
            Fibre::Viscose => "viscose",
            Fibre::Acrylic => "acrylic",
            Fibre::Cashmere => "cashmere",
        }
    }
}

/// Ground-truth tactile attributes, each 0..1, derived from the structure.
/// They are the reference for "feels similar".
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Attributes {
    /// Perceived roughness: relief relative to yarn spacing, reduced by fuzz.
    pub roughness: f32,
    /// Thread density (cover).
    pub density: f32,
    /// Softness: compressibility and low bending stiffness.
    pub softness: f32,
    /// Fuzziness / hairiness.
    pub fuzziness: f32,
    /// Thickness / bulk.
    pub thickness: f32,
    /// Stretchiness (knits high, wovens low).
    pub stretch: f32,
    /// Slipperiness / smoothness (satin and silk high).
    pub slipperiness: f32,
}

impl Attributes {
    /// The attributes' names, in the order of [`Attributes::to_vec`].
    pub const NAMES: [&'static str; 7] = [
        "roughness",
        "density",
        "softness",
        "fuzziness",
        "thickness",
        "stretch",
        "slipperiness",
    ];

    /// As a vector in a fixed order (roughness, density, softness, fuzziness,
    /// thickness, stretch, slipperiness: [`Attributes::NAMES`]).
    pub fn to_vec(&self) -> [f32; 7] {
        [
            self.roughness,
            self.density,
            self.softness,
            self.fuzziness,
            self.thickness,
            self.stretch,
            self.slipperiness,
        ]
    }
}

/// One textile sample.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Textile {
    /// "T001".."T119" for training, "U01".."U20" for unseen.
    pub id: String,
    pub name: String,
    pub book: Book,
    pub structure: Structure,
    pub fibre: Fibre,
    /// Warp ends (or knit wales, or pile tufts) per cm.
    pub warp_per_cm: f32,
    /// Weft picks (or knit courses) per cm.
    pub weft_per_cm: f32,
    /// Yarn diameter in mm.
    pub yarn_diameter_mm: f32,
    /// Peak-to-valley relief of the surface in mm.
    pub relief_mm: f32,
    /// Hairiness / fuzz 0..1.
    pub fuzz: f32,
    /// Compressibility 0..1 (1 = very soft, relief flattens under the gel).
    pub compliance: f32,
    /// Fibre bending stiffness 0..1.
    pub stiffness: f32,
    /// Yarn unevenness (slubs, spacing jitter) 0..1.
    pub irregularity: f32,
    /// Thickness in mm.
    pub thickness_mm: f32,
    /// Seed of this textile's micro-structure (fibre placement, yarn jitter).
    pub micro_seed: u64,
    /// The textile this one is a near-twin of (same structure and counts,
    /// different fibre), if any.
    pub twin_of: Option<String>,
    pub attributes: Attributes,
}

/// A versioned set of textiles.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Catalogue {
    pub version: u32,
    pub textiles: Vec<Textile>,
}

mod templates;
use templates::*;
use Fibre::*;

fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + (b - a) * t
}

/// A splitmix64 step, used to derive independent seeds.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Stable 64-bit hash of a string (FNV-1a then splitmix).
pub fn hash_str(s: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in s.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    mix64(h)
}

#[allow(clippy::too_many_arguments)]
fn make_textile(
    id: String,
    book: Book,
    structure: Structure,
    fibre: Fibre,
    warp: f32,
    weft: f32,
    cover: f32,
    relief_frac: f32,
    rng: &mut ChaCha8Rng,
    twin_of: Option<String>,
    version: u32,
) -> Textile {
    let (stiff, hair, irr, comp) = fibre.properties();
    let spacing_mm = 10.0 / warp;
    let family = structure.family();
    let (diam, relief, thickness) = match family {
        Family::Pile | Family::Fleece | Family::Felt => {
            let d = spacing_mm * cover;
            let pile = match structure {
                Structure::Corduroy { .. } => lerp(0.9, 1.6, rng.gen::<f32>()),
                Structure::Fleece => lerp(1.5, 3.0, rng.gen::<f32>()),
                Structure::Felt => lerp(1.0, 3.0, rng.gen::<f32>()),
                Structure::Plush => lerp(2.0, 4.0, rng.gen::<f32>()),
                _ => lerp(0.6, 1.2, rng.gen::<f32>()),
            };
            (d, pile * relief_frac * 0.4, pile + 0.3)
        }
        // catalogue 2 families
        Family::Loop => {
            let d = spacing_mm * cover;
            (
                d,
                d * relief_frac * lerp(0.9, 1.3, rng.gen::<f32>()),
                lerp(1.5, 3.0, rng.gen::<f32>()),
            )
        }
        Family::Tuft => {
            let d = spacing_mm * cover;
            (
                d,
                lerp(0.5, 0.9, rng.gen::<f32>()) * relief_frac,
                lerp(5.0, 10.0, rng.gen::<f32>()),
            )
        }
        Family::Soft => {
            let d = spacing_mm * cover;
            (d, d * relief_frac, lerp(3.0, 12.0, rng.gen::<f32>()))
        }
        Family::Terry => {
            let d = spacing_mm * cover * 0.5;
            (
                d,
                lerp(0.5, 0.9, rng.gen::<f32>()) * relief_frac,
                lerp(2.5, 5.0, rng.gen::<f32>()),
            )
        }
        _ => {
            let d = spacing_mm * cover;
            (
                d,
                d * relief_frac,
                d * 2.0 * lerp(0.9, 1.2, rng.gen::<f32>()),
            )
        }
    };
    let jitter =
        |rng: &mut ChaCha8Rng, v: f32, s: f32| (v + s * (rng.gen::<f32>() - 0.5)).clamp(0.0, 1.0);
    let extra_fuzz = match family {
        Family::Fleece | Family::Felt => 0.4,
        Family::Pile => 0.2,
        Family::Soft => 0.45,
        Family::Loop | Family::Tuft => 0.15,
        Family::Satin => -0.2,
        _ => 0.0,
    };
    let fuzz = jitter(rng, hair + extra_fuzz, 0.15);
    let compliance_base = match family {
        Family::Pile | Family::Fleece | Family::Terry => 0.35,
        Family::Knit | Family::Rib | Family::Felt => 0.2,
        Family::Loop | Family::Tuft => 0.3,
        Family::Soft => 0.6,
        _ => 0.0,
    };
    let compliance = jitter(rng, comp * 0.7 + compliance_base, 0.1);
    let stiffness = jitter(rng, stiff, 0.1);
    let irregularity = jitter(rng, irr, 0.1);
    let micro_seed = hash_str(&format!("micro/{id}/{version}"));
    let name = format!(
        "{} {}, {:.0}x{:.0}/cm",
        fibre.name(),
        structure.label(),
        warp,
        weft
    );
    let mut t = Textile {
        id,
        name,
        book,
        structure,
        fibre,
        warp_per_cm: warp,
        weft_per_cm: weft,
        yarn_diameter_mm: diam,
        relief_mm: relief,
        fuzz,
        compliance,
        stiffness,
        irregularity,
        thickness_mm: thickness,
        micro_seed,
        twin_of,
        attributes: Attributes {
            roughness: 0.0,
            density: 0.0,
            softness: 0.0,
            fuzziness: 0.0,
            thickness: 0.0,
            stretch: 0.0,
            slipperiness: 0.0,
        },
    };
    t.attributes = derive_attributes(&t);
    t
}

/// Ground-truth attributes from the physical parameters.
pub fn derive_attributes(t: &Textile) -> Attributes {
    let family = t.structure.family();
    let spacing = 10.0 / t.warp_per_cm.max(1.0);
    let float_len = match t.structure {
        Structure::Satin { harness } => harness as f32 - 1.0,
        Structure::Twill { over, .. } | Structure::Herringbone { over, .. } => over as f32,
        Structure::Basket { group } => group as f32,
        _ => 1.0,
    };
    let rough_geom = (t.relief_mm / spacing).clamp(0.0, 2.0) / 2.0;
    let roughness =
        (0.15 + 0.9 * rough_geom + 0.2 * t.irregularity - 0.25 * t.fuzz - 0.05 * float_len
            + if family == Family::Crepe { 0.2 } else { 0.0 })
        .clamp(0.0, 1.0);
    let cover = (t.yarn_diameter_mm / spacing).clamp(0.0, 1.5) / 1.5;
    let density =
        (0.5 * cover + 0.5 * ((t.warp_per_cm + t.weft_per_cm) / 140.0).min(1.0)).clamp(0.0, 1.0);
    let softness =
        (0.55 * t.compliance + 0.35 * (1.0 - t.stiffness) + 0.1 * t.fuzz).clamp(0.0, 1.0);
    let thickness = (t.thickness_mm / 5.0).clamp(0.0, 1.0);
    let stretch = match family {
        Family::Knit => 0.7,
        Family::Rib => 0.9,
        Family::Fleece => 0.5,
        Family::Crepe => 0.3,
        Family::Felt => 0.05,
        Family::Soft => 0.4,
        Family::Loop => 0.3,
        _ => 0.1,
    } * (1.0 - 0.3 * t.stiffness)
        + 0.05;
    let slipperiness = ((1.0 - roughness) * 0.5 + 0.1 * float_len - 0.4 * t.fuzz
        + if t.fibre == Fibre::Silk { 0.25 } else { 0.0 })
    .clamp(0.0, 1.0);
    Attributes {
        roughness,
        density,
        softness,
        fuzziness: t.fuzz,
        thickness,
        stretch: stretch.clamp(0.0, 1.0),
        slipperiness,
    }
}

impl Catalogue {
    /// The built-in catalogue: 119 training + 20 unseen textiles (version 1).
    pub fn builtin() -> Catalogue {
        Self::build(CATALOGUE_VERSION)
    }

    /// Built-in catalogue `version` (1 or 2); None for an unknown version.
    /// Both have the ids T001..T119 and U01..U20; version 2 has more
    /// families (gauze, plush, boucle, tufted, soft low-texture fabrics) and
    /// is rendered by the version-2 simulator (bolts, sensor units, camera).
    pub fn version(version: u32) -> Option<Catalogue> {
        match version {
            1 => Some(Self::build(1)),
            2 => Some(Self::build(2)),
            _ => None,
        }
    }

    fn build(version: u32) -> Catalogue {
        let v2 = version >= 2;
        let mut rng = ChaCha8Rng::seed_from_u64(if v2 {
            0x007e_1e77_11e5_0002
        } else {
            0x007e_1e77_11e5_u64
        });
        let tpls = if v2 { templates_v2() } else { templates() };
        let mut textiles: Vec<Textile> = Vec::new();
        let mut next_id = 1usize;
        let new_id = |n: &mut usize| {
            let s = format!("T{:03}", *n);
            *n += 1;
            s
        };
        let twins = if v2 { twin_groups_v2() } else { twin_groups() };
        for (ti, tpl) in tpls.iter().enumerate() {
            let mut made = 0usize;
            if let Some((_, fibres)) = twins.iter().find(|(i, _)| *i == ti) {
                let warp = lerp(tpl.count.0, tpl.count.1, rng.gen());
                let weft = warp * lerp(tpl.balance.0, tpl.balance.1, rng.gen());
                let cover = lerp(tpl.cover.0, tpl.cover.1, rng.gen());
                let relief = lerp(tpl.relief.0, tpl.relief.1, rng.gen());
                let mut first: Option<String> = None;
                for &f in fibres.iter() {
                    let id = new_id(&mut next_id);
                    let mut trng = ChaCha8Rng::seed_from_u64(hash_str(&id));
                    textiles.push(make_textile(
                        id.clone(),
                        Book::Training,
                        tpl.structure,
                        f,
                        warp,
                        weft,
                        cover,
                        relief,
                        &mut trng,
                        first.clone(),
                        version,
                    ));
                    first.get_or_insert(id);
                    made += 1;
                }
            }
            while made < tpl.n {
                let f = tpl.fibres[made % tpl.fibres.len()];
                let warp = lerp(tpl.count.0, tpl.count.1, rng.gen());
                let weft = warp * lerp(tpl.balance.0, tpl.balance.1, rng.gen());
                let cover = lerp(tpl.cover.0, tpl.cover.1, rng.gen());
                let relief = lerp(tpl.relief.0, tpl.relief.1, rng.gen());
                let id = new_id(&mut next_id);
                let mut trng = ChaCha8Rng::seed_from_u64(hash_str(&id));
                textiles.push(make_textile(
                    id,
                    Book::Training,
                    tpl.structure,
                    f,
                    warp,
                    weft,
                    cover,
                    relief,
                    &mut trng,
                    None,
                    version,
                ));
                made += 1;
            }
        }
        debug_assert_eq!(textiles.len(), 119);
        // Unseen book: new draws (and some structure variants the training
        // book does not have), rejected if too close to any training textile.
        let unseen_v1 = [
            (Structure::Plain, Linen),
            (Structure::Twill { over: 2, under: 1 }, Linen),
            (Structure::Twill { over: 3, under: 1 }, Cashmere),
            (Structure::Satin { harness: 5 }, Nylon),
            (Structure::Basket { group: 3 }, Cotton),
            (Structure::Crepe, Cotton),
            (Structure::Jersey, Cashmere),
            (Structure::Rib { knit: 2, purl: 1 }, Cotton),
            (Structure::Velvet, Wool),
            (Structure::Corduroy { wale_mm: 4.0 }, Cotton),
            (Structure::Terry { loop_mm: 2.2 }, Cotton),
            (Structure::Fleece, Cashmere),
            (Structure::Felt, Acrylic),
            (
                Structure::Herringbone {
                    over: 2,
                    under: 2,
                    band: 6,
                },
                Cashmere,
            ),
            (Structure::Ripstop { grid: 8 }, Cotton),
            (Structure::Plain, Acrylic),
            (Structure::Twill { over: 2, under: 2 }, Silk),
            (Structure::Satin { harness: 8 }, Viscose),
            (Structure::Jersey, Silk),
            (Structure::Rib { knit: 1, purl: 1 }, Silk),
        ];
        let unseen_v2 = unseen_structures_v2();
        let unseen_structs: &[(Structure, Fibre)] = if v2 { &unseen_v2 } else { &unseen_v1 };
        let mut urng = ChaCha8Rng::seed_from_u64(if v2 {
            0x0005_ee11_0002
        } else {
            0x0005_ee11_u64
        });
        for (k, (s, f)) in unseen_structs.iter().enumerate() {
            let tpl = tpls
                .iter()
                .find(|t| t.structure.family() == s.family())
                .expect("every family has a template");
            let id = format!("U{:02}", k + 1);
            let mut tries = 0;
            loop {
                let warp = lerp(tpl.count.0 * 0.9, tpl.count.1 * 1.1, urng.gen());
                let weft = warp * lerp(tpl.balance.0, tpl.balance.1, urng.gen());
                let cover = lerp(tpl.cover.0, tpl.cover.1, urng.gen());
                let relief = lerp(tpl.relief.0, tpl.relief.1, urng.gen());
                let mut trng = ChaCha8Rng::seed_from_u64(hash_str(&id));
                let t = make_textile(
                    id.clone(),
                    Book::Unseen,
                    *s,
                    *f,
                    warp,
                    weft,
                    cover,
                    relief,
                    &mut trng,
                    None,
                    version,
                );
                tries += 1;
                let too_close = textiles
                    .iter()
                    .any(|o| o.book == Book::Training && is_copy(o, &t));
                if !too_close || tries > 50 {
                    textiles.push(t);
                    break;
                }
            }
        }
        Catalogue { version, textiles }
    }

    /// Look a textile up by id.
    pub fn get(&self, id: &str) -> Option<&Textile> {
        self.textiles.iter().find(|t| t.id == id)
    }

    /// The training book.
    pub fn training(&self) -> impl Iterator<Item = &Textile> {
        self.textiles.iter().filter(|t| t.book == Book::Training)
    }

    /// The unseen book.
    pub fn unseen(&self) -> impl Iterator<Item = &Textile> {
        self.textiles.iter().filter(|t| t.book == Book::Unseen)
    }

    /// Pairs of near-twins (a, b) with b.twin_of == a.
    pub fn twin_pairs(&self) -> Vec<(&Textile, &Textile)> {
        self.textiles
            .iter()
            .filter_map(|b| {
                let a = self.get(b.twin_of.as_deref()?)?;
                Some((a, b))
            })
            .collect()
    }
}

/// Whether two textiles are the same fabric for practical purposes: same
/// structure and fibre, and counts within 10 %.
pub fn is_copy(a: &Textile, b: &Textile) -> bool {
    a.structure == b.structure
        && a.fibre == b.fibre
        && (a.warp_per_cm / b.warp_per_cm - 1.0).abs() < 0.10
        && (a.weft_per_cm / b.weft_per_cm - 1.0).abs() < 0.10
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_ids_twins() {
        let c = Catalogue::builtin();
        assert_eq!(c.training().count(), 119);
        assert_eq!(c.unseen().count(), 20);
        assert_eq!(c.get("T001").unwrap().book, Book::Training);
        assert_eq!(c.get("T119").unwrap().book, Book::Training);
        assert_eq!(c.get("U20").unwrap().book, Book::Unseen);
        assert!(c.get("T120").is_none());
        assert!(c.twin_pairs().len() >= 6);
        for (a, b) in c.twin_pairs() {
            assert_eq!(a.structure, b.structure);
            assert_eq!(a.warp_per_cm, b.warp_per_cm);
            assert_ne!(a.fibre, b.fibre);
        }
        for u in c.unseen() {
            for t in c.training() {
                assert!(!is_copy(t, u), "{} copies {}", u.id, t.id);
            }
        }
        for t in &c.textiles {
            for a in t.attributes.to_vec() {
                assert!((0.0..=1.0).contains(&a), "{} attribute {a}", t.id);
            }
        }
        assert_eq!(c, Catalogue::builtin());
        assert_eq!(Catalogue::version(1), Some(c));
        assert!(Catalogue::version(3).is_none());
    }

    #[test]
    fn version_2_counts_twins_and_new_families() {
        let c = Catalogue::version(2).unwrap();
        assert_eq!(c.version, 2);
        assert_eq!(c.training().count(), 119);
        assert_eq!(c.unseen().count(), 20);
        assert!(c.twin_pairs().len() >= 7);
        for (a, b) in c.twin_pairs() {
            assert_eq!(a.structure, b.structure);
            assert_ne!(a.fibre, b.fibre);
        }
        for f in Family::ALL_V2 {
            assert!(
                c.training().any(|t| t.structure.family() == f),
                "no {f:?} in catalogue 2"
            );
        }
        let soft = c
            .training()
            .filter(|t| t.structure.family() == Family::Soft)
            .count();
        assert!(soft >= 8, "{soft} soft textiles");
        for u in c.unseen() {
            for t in c.training() {
                assert!(!is_copy(t, u), "{} copies {}", u.id, t.id);
            }
        }
        // the same ids, different cloth than version 1
        let v1 = Catalogue::builtin();
        assert_ne!(
            c.get("T050").unwrap().micro_seed,
            v1.get("T050").unwrap().micro_seed
        );
        assert_eq!(c, Catalogue::version(2).unwrap());
    }
}
