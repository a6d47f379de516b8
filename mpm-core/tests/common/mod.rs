//! Builders for the validation problems.
#![allow(dead_code)]

use mpm_core::scenario::lattice::cell_centred;
use mpm_core::{GridSpec, Material, Particles, Setup, Wall, WallKind};

pub type Vec3 = [f64; 3];

/// Particles at `ppc^3` points per cell of size `dx` filling `[lo, hi]`, kept by `keep`.
pub fn fill(
    material: &Material,
    lo: Vec3,
    hi: Vec3,
    dx: f64,
    ppc: usize,
    keep: impl Fn(Vec3) -> bool,
    v: impl Fn(Vec3) -> Vec3,
) -> Particles {
    let h = dx / ppc as f64;
    let n: [usize; 3] = std::array::from_fn(|d| ((hi[d] - lo[d]) / h).round() as usize);
    let pts = cell_centred(lo, [h; 3], n, keep);
    let mass = material.density * h * h * h;
    let mut p = Particles::with_capacity(pts.len());
    for x in pts {
        p.push(x, v(x), mass, material.density, material.reference_sound_speed());
    }
    p
}

/// A laterally confined column `[0, w]^2 x [0, h]` (slip walls on its four sides and at
/// z = 0): uniaxial strain, so waves travel at the P-wave speed.
pub fn confined_column(material: Material, w: f64, h: f64, dx: f64, v: impl Fn(Vec3) -> Vec3) -> Setup {
    let particles = fill(&material, [0.0; 3], [w, w, h], dx, 2, |_| true, v);
    let n = (w / dx).round() as usize;
    let nz = (h / dx).round() as usize + 4;
    let walls = vec![
        Wall { axis: 0, position: 0.0, kind: WallKind::Slip },
        Wall { axis: 0, position: w, kind: WallKind::Slip },
        Wall { axis: 1, position: 0.0, kind: WallKind::Slip },
        Wall { axis: 1, position: w, kind: WallKind::Slip },
        Wall { axis: 2, position: 0.0, kind: WallKind::Slip },
    ];
    Setup {
        scenario: "column".into(),
        model: "column".into(),
        particles,
        material,
        grid: GridSpec { dx, anchor: [0.0; 3], cells: [n, n, nz] },
        walls,
        spacing: [dx / 2.0; 3],
        part: None,
    }
}

/// Elastic copper (Table 1 elastic constants, no yield, linear EOS).
pub fn elastic_copper() -> Material {
    Material::elastic("elastic copper", 8930.0, 117.0e9, 0.35)
}

/// Two spheres of radius `r` approaching each other along x at `v` each, no walls.
pub fn two_spheres(material: Material, r: f64, dx: f64, v: f64, ppc: usize) -> Setup {
    let c = r + dx;
    let lo = [-c - r, -r, -r];
    let hi = [c + r, r, r];
    let particles = fill(
        &material,
        lo,
        hi,
        dx,
        ppc,
        |x| {
            let a = (x[0] + c).powi(2) + x[1] * x[1] + x[2] * x[2];
            let b = (x[0] - c).powi(2) + x[1] * x[1] + x[2] * x[2];
            a <= r * r || b <= r * r
        },
        |x| if x[0] < 0.0 { [v, 0.0, 0.0] } else { [-v, 0.0, 0.0] },
    );
    Setup {
        scenario: "spheres".into(),
        model: "spheres".into(),
        particles,
        material,
        grid: GridSpec { dx, anchor: [lo[0] - 2.0 * dx, lo[1] - 2.0 * dx, lo[2] - 2.0 * dx], cells: [1, 1, 1] },
        walls: vec![],
        spacing: [dx / ppc as f64; 3],
        part: None,
    }
}

/// A small hypervelocity-like impact in free flight: a lead sphere at 3 km/s striking a
/// lead plate, no walls, adaptive grid.
pub fn mini_impact() -> Setup {
    let material = Material::lead(mpm_core::MgForm::default());
    let dx = 1.0e-3;
    let r = 2.0e-3;
    let (plate_lo, plate_hi) = ([-6e-3, -6e-3, -1.5e-3], [6e-3, 6e-3, 0.0]);
    let mut p = fill(&material, plate_lo, plate_hi, dx, 2, |_| true, |_| [0.0; 3]);
    let s = fill(
        &material,
        [-r, -r, 0.25e-3],
        [r, r, 2.0 * r + 0.25e-3],
        dx,
        2,
        |x| x[0] * x[0] + x[1] * x[1] + (x[2] - r - 0.25e-3).powi(2) <= r * r,
        |_| [0.0, 0.0, -3000.0],
    );
    for i in 0..s.len() {
        p.push(s.x[i], s.v[i], s.mass[i], s.rho[i], s.sound[i]);
    }
    Setup {
        scenario: "mini-impact".into(),
        model: "mini-impact".into(),
        particles: p,
        material,
        grid: GridSpec { dx, anchor: [0.0; 3], cells: [1, 1, 1] },
        walls: vec![],
        spacing: [dx / 2.0; 3],
        part: None,
    }
}

/// A rayon pool of `n` threads, as a simulation takes it.
pub fn pool(n: usize) -> std::sync::Arc<rayon::ThreadPool> {
    std::sync::Arc::new(rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap())
}
