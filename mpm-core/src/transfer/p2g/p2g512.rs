//! P2G at AVX-512 with a particle's 8 nodes as the 8 lanes of a register.
//!
//! The blocked P2G of [`super::P2g`] puts 4 particles in the lanes and then adds each
//! particle's values to its 8 node records one node at a time: 33 instructions per node in
//! its compiled loop, a third of them taking single lanes out of vectors. Here one
//! particle's shape functions are vectors over its 8 nodes (node `q = a + 2 b + 4 c` in lane
//! `q`), so are the 7 values it adds to them (`m S`, `m S v`, `-V sigma . G`): P2G took 0.62
//! of the blocked form's time (median of 8 alternated runs of serial Model 1).
//!
//! The particles come in runs of one cell (the cell order, [`crate::order`]: about 8 a cell
//! in the Taylor models). At the start of a run its 8 nodes' 64-byte records `[m, p, f, 0]`
//! are loaded and transposed (an 8 x 8 transpose: value `i` of node `q` in lane `q` of
//! vector `i`), each particle of the run adds its 7 vectors to them in registers, and at
//! the run's end they are transposed back and stored: two transposes and 16 memory
//! operations a run, where adding each particle's transposed values to the records took
//! one transpose and 24 memory operations a particle. The scatter with the locate pass
//! took 0.79 of that form's time, the step 0.96 (medians of 10 alternated runs of serial
//! Model 1). Each node value still receives the particles' values one at a time in their
//! order, `((record + a_1) + a_2) + ...`, so the sums are bitwise those of one particle at
//! a time.
//!
//! Every lane performs [`crate::shape::evaluate`]'s and the blocked P2G's operations in their
//! order (`S_q = nx (ny nz)`, its gradient `(dx (ny nz), (nx dy) nz, (nx ny) dz)`, `sigma . G`
//! summed `x, y, z`, `f - V t` as `f + (-1 V t)`, which IEEE arithmetic makes the same), so
//! every node sum is bitwise the blocked form's: the test
//! `blocked_p2g_is_bitwise_one_particle_at_a_time` holds the two to each other whenever the CPU
//! has AVX-512 (the kernel's `scatter` runs the blocked form one particle at a time), and
//! `dispatch_levels_agree_bitwise` whole runs against the baseline.

use super::{Cursors, P2g, Target, P2G_WIDTH};
use std::arch::x86_64::*;

/// `kernel`'s additions for the particles `ids`, in order, into `data` (see the module).
///
/// One function of 81 lines, a kernel: a particle's weights and its record live in vector
/// registers across the whole body; split into calls, they would pass through memory.
///
/// # Safety
/// The CPU must execute AVX-512F (`SimdLevel::Avx512.is_available()`).
#[target_feature(enable = "avx512f,avx2")]
pub(super) unsafe fn scatter<const BODY: bool, D: Target<P2G_WIDTH> + ?Sized>(
    kernel: &P2g<'_, BODY>,
    ids: impl Iterator<Item = usize>,
    nodes: &mut Cursors<'_>,
    data: &mut D,
) {
    let pt = kernel.particles;
    let inv_dx = kernel.geom.inv_dx;
    let (lo, hi) = (_mm512_set1_pd(-inv_dx), _mm512_set1_pd(inv_dx));
    // The lanes q = a + 2 b + 4 c with a = 1 (mask 0xAA), b = 1 (0xCC), c = 1 (0xF0).
    let (a1, b1, c1) = (0xAA, 0xCC, 0xF0);
    let (ga, gb, gc) =
        (_mm512_mask_blend_pd(a1, lo, hi), _mm512_mask_blend_pd(b1, lo, hi), _mm512_mask_blend_pd(c1, lo, hi));
    let minus_one = _mm512_set1_pd(-1.0);
    let body: [__m512d; 3] = std::array::from_fn(|i| _mm512_set1_pd(kernel.body_force[i]));
    // The run of particles in one cell being added: its cell's key, its nodes, and their
    // records transposed (value `i` of node `q` in lane `q` of `sums[i]`). The key is the
    // cell as two scalars (fewer than 2^32 cells an axis, `Located`): the cell compared as
    // an array went through the stack, and the load of its three stores stalled (P2G 1.22
    // of the one-transpose-a-particle form's time instead of 0.79).
    let mut run_key = (u64::MAX, usize::MAX);
    let mut idx = [0usize; 8];
    let mut sums = [_mm512_setzero_pd(); 8];
    for p in ids {
        // Cell and local coordinates (`shape::local_coords`), `n0 = 1 - r` as `shape::at`.
        let (cell, n1) = (kernel.located.cell(p), kernel.located.r(p));
        let key = (cell[0] as u64 | (cell[1] as u64) << 32, cell[2]);
        if key != run_key {
            if run_key.1 != usize::MAX {
                store(&idx, sums, data);
            }
            run_key = key;
            idx = nodes.target(cell);
            sums = load(&idx, data);
        }
        let n0 = n1.map(|r| 1.0 - r);
        let nx = _mm512_mask_blend_pd(a1, _mm512_set1_pd(n0[0]), _mm512_set1_pd(n1[0]));
        let ny = _mm512_mask_blend_pd(b1, _mm512_set1_pd(n0[1]), _mm512_set1_pd(n1[1]));
        let nz = _mm512_mask_blend_pd(c1, _mm512_set1_pd(n0[2]), _mm512_set1_pd(n1[2]));
        let nyz = _mm512_mul_pd(ny, nz);
        let w = _mm512_mul_pd(nx, nyz);
        let gx = _mm512_mul_pd(ga, nyz);
        let gy = _mm512_mul_pd(_mm512_mul_pd(nx, gb), nz);
        let gz = _mm512_mul_pd(_mm512_mul_pd(nx, ny), gc);
        let m = pt.mass[p];
        let vol = _mm512_set1_pd(m / pt.rho[p]);
        let mw = _mm512_mul_pd(_mm512_set1_pd(m), w);
        let v = pt.v[p];
        let st = &pt.stress[p];
        // Row i of the stress (Voigt order): t_i = sigma_ix G_x + sigma_iy G_y + sigma_iz G_z.
        let rows = [[st[0], st[5], st[4]], [st[5], st[1], st[3]], [st[4], st[3], st[2]]];
        let f: [__m512d; 3] = std::array::from_fn(|i| {
            let sx = _mm512_mul_pd(_mm512_set1_pd(rows[i][0]), gx);
            let sy = _mm512_mul_pd(_mm512_set1_pd(rows[i][1]), gy);
            let sz = _mm512_mul_pd(_mm512_set1_pd(rows[i][2]), gz);
            let vt = _mm512_mul_pd(vol, _mm512_add_pd(_mm512_add_pd(sx, sy), sz));
            if BODY {
                _mm512_sub_pd(_mm512_mul_pd(mw, body[i]), vt)
            } else {
                // -vt exactly, so that `f + (-vt)` is bitwise `f - vt` for every `f` (`0 - vt`
                // is +0 for `vt = +0`, and `-0 + 0` is not `-0 - 0`).
                _mm512_mul_pd(vt, minus_one)
            }
        });
        let mv: [__m512d; 3] = std::array::from_fn(|i| _mm512_mul_pd(mw, _mm512_set1_pd(v[i])));
        // Lane q of [mw, mv, f] is node q's: added to the run's sums of each record value.
        sums = [
            _mm512_add_pd(sums[0], mw),
            _mm512_add_pd(sums[1], mv[0]),
            _mm512_add_pd(sums[2], mv[1]),
            _mm512_add_pd(sums[3], mv[2]),
            _mm512_add_pd(sums[4], f[0]),
            _mm512_add_pd(sums[5], f[1]),
            _mm512_add_pd(sums[6], f[2]),
            sums[7],
        ];
    }
    if run_key.1 != usize::MAX {
        store(&idx, sums, data);
    }
}

/// The records of the nodes `idx` out of `data`, transposed.
#[target_feature(enable = "avx512f")]
#[inline]
fn load<D: Target<P2G_WIDTH> + ?Sized>(idx: &[usize; 8], data: &mut D) -> [__m512d; 8] {
    let mut records = [_mm512_setzero_pd(); 8];
    for (r, &i) in records.iter_mut().zip(idx) {
        // SAFETY: the pointer is to record `i` of `data`, 8 `f64`; the unaligned load reads
        // exactly those.
        *r = unsafe { _mm512_loadu_pd(data.at(i).as_ptr()) };
    }
    transpose(records)
}

/// [`load`]'s records, transposed back, into `data`.
#[target_feature(enable = "avx512f")]
#[inline]
fn store<D: Target<P2G_WIDTH> + ?Sized>(idx: &[usize; 8], sums: [__m512d; 8], data: &mut D) {
    for (&i, &r) in idx.iter().zip(&transpose(sums)) {
        // SAFETY: record `i` of `data`, 8 `f64` borrowed mutably here; the store writes
        // exactly those.
        unsafe { _mm512_storeu_pd(data.at(i).as_mut_ptr(), r) };
    }
}

/// The 8 x 8 transpose: lane `j` of row `i` is lane `i` of the result's row `j`.
#[target_feature(enable = "avx512f")]
#[inline]
fn transpose(rows: [__m512d; 8]) -> [__m512d; 8] {
    // Lane i of a result: index < 8 from the first operand, index - 8 from the second:
    // pairs of 128-bit halves, then 256-bit halves.
    let pairs_lo = _mm512_set_epi64(13, 12, 5, 4, 9, 8, 1, 0);
    let pairs_hi = _mm512_set_epi64(15, 14, 7, 6, 11, 10, 3, 2);
    let halves_lo = _mm512_set_epi64(11, 10, 9, 8, 3, 2, 1, 0);
    let halves_hi = _mm512_set_epi64(15, 14, 13, 12, 7, 6, 5, 4);
    let [r0, r1, r2, r3, r4, r5, r6, r7] = rows;
    let t0 = _mm512_unpacklo_pd(r0, r1);
    let t1 = _mm512_unpackhi_pd(r0, r1);
    let t2 = _mm512_unpacklo_pd(r2, r3);
    let t3 = _mm512_unpackhi_pd(r2, r3);
    let t4 = _mm512_unpacklo_pd(r4, r5);
    let t5 = _mm512_unpackhi_pd(r4, r5);
    let t6 = _mm512_unpacklo_pd(r6, r7);
    let t7 = _mm512_unpackhi_pd(r6, r7);
    let u0 = _mm512_permutex2var_pd(t0, pairs_lo, t2);
    let u1 = _mm512_permutex2var_pd(t0, pairs_hi, t2);
    let u2 = _mm512_permutex2var_pd(t1, pairs_lo, t3);
    let u3 = _mm512_permutex2var_pd(t1, pairs_hi, t3);
    let u4 = _mm512_permutex2var_pd(t4, pairs_lo, t6);
    let u5 = _mm512_permutex2var_pd(t4, pairs_hi, t6);
    let u6 = _mm512_permutex2var_pd(t5, pairs_lo, t7);
    let u7 = _mm512_permutex2var_pd(t5, pairs_hi, t7);
    [
        _mm512_permutex2var_pd(u0, halves_lo, u4),
        _mm512_permutex2var_pd(u2, halves_lo, u6),
        _mm512_permutex2var_pd(u1, halves_lo, u5),
        _mm512_permutex2var_pd(u3, halves_lo, u7),
        _mm512_permutex2var_pd(u0, halves_hi, u4),
        _mm512_permutex2var_pd(u2, halves_hi, u6),
        _mm512_permutex2var_pd(u1, halves_hi, u5),
        _mm512_permutex2var_pd(u3, halves_hi, u7),
    ]
}
