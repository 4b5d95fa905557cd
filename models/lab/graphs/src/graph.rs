//! Fixed (untrained) descriptors written as ONNX graphs that follow the
//! Telextiles encoder contract, so that the daemon can run a classical
//! descriptor exactly as it runs a trained encoder: input `frames` f32
//! `[N, 3, S, S]` (DIGIT-normalised, as the daemon's preprocessing writes
//! it), output `embedding` f32 `[N, D]`, `telextiles.*` metadata.
//!
//! * `fft-radial`: the radially averaged log power spectrum of the
//!   Hann-windowed grey crop ([`crate::baselines`]'s `Fft`). The 2D DFT is
//!   two pairs of matrix products with fixed cosine and sine matrices
//!   (`Re = C X C - S X S`, `Im = -(C X S + S X C)`), the radial average one
//!   more product with a fixed `S*S x (S/2 - 1)` binning matrix.
//! * `pixels`: 16x16 block means per channel minus the channel mean.
//!
//! Each graph reproduces the Rust descriptor of `baselines.rs` on the same
//! pixels (tested to 1e-3 after L2 normalisation: the graph computes in
//! f32, the Rust reference in f64). The graph does not
//! L2-normalise (consumers do; a blank frame gives zeros, not NaN).

use anyhow::{ensure, Context, Result};
use onnx_ir::{AttributeProto, AttributeType, Message, ModelProto, NodeProto, TensorProto};
use protobuf::EnumOrUnknown;
use std::f64::consts::PI;

use crate::baselines::{radial_bins, BaselineKind};

/// The cells of rows 0..=n/2 of an `n` x `n` spectrum (index `ky * n + kx`)
/// that fall in radius bins 1..n/2, with their radius (as
/// [`radial_bins`], restricted to the half plane).
pub fn half_plane_bins(n: usize) -> Vec<(usize, usize)> {
    radial_bins(n)
        .0
        .into_iter()
        .filter(|&(cell, _)| cell / n <= n / 2)
        .collect()
}
use crate::ortrun::{contract_props, INPUT_NAME, OUTPUT_NAME};
use crate::preprocess::{DIGIT_MEAN, DIGIT_STD};

/// ITU-R BT.601 luma weights (the descriptors' grey).
pub const GREY: [f32; 3] = [0.299, 0.587, 0.114];

/// ONNX opset the graphs use.
const OPSET: i64 = 18;
const FLOAT: i32 = 1;
const INT32: i32 = 6;
const INT64: i32 = 7;

/// A small graph builder: nodes and initialisers with generated names.
#[derive(Default)]
struct Builder {
    nodes: Vec<NodeProto>,
    inits: Vec<TensorProto>,
    n: usize,
}

fn attr_int(name: &str, v: i64) -> AttributeProto {
    let mut a = AttributeProto::new();
    a.name = name.into();
    a.type_ = EnumOrUnknown::new(AttributeType::INT);
    a.i = v;
    a
}

fn attr_str(name: &str, v: &str) -> AttributeProto {
    let mut a = AttributeProto::new();
    a.name = name.into();
    a.type_ = EnumOrUnknown::new(AttributeType::STRING);
    a.s = v.as_bytes().to_vec().into();
    a
}

fn attr_ints(name: &str, v: &[i64]) -> AttributeProto {
    let mut a = AttributeProto::new();
    a.name = name.into();
    a.type_ = EnumOrUnknown::new(AttributeType::INTS);
    a.ints = v.to_vec();
    a
}

impl Builder {
    fn name(&mut self, hint: &str) -> String {
        self.n += 1;
        format!("{hint}_{}", self.n)
    }

    /// An initialiser of `data_type` holding `raw` (little-endian values).
    fn tensor(&mut self, hint: &str, dims: &[i64], data_type: i32, raw: Vec<u8>) -> String {
        let mut t = TensorProto::new();
        t.name = self.name(hint);
        t.dims = dims.to_vec();
        t.data_type = data_type;
        t.raw_data = raw.into();
        let n = t.name.clone();
        self.inits.push(t);
        n
    }

    fn f32s(&mut self, hint: &str, dims: &[i64], data: Vec<f32>) -> String {
        assert_eq!(dims.iter().product::<i64>() as usize, data.len(), "{hint}");
        let raw = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.tensor(hint, dims, FLOAT, raw)
    }

    fn i64s(&mut self, hint: &str, data: Vec<i64>) -> String {
        let raw = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.tensor(hint, &[data.len() as i64], INT64, raw)
    }

    fn i32s(&mut self, hint: &str, dims: &[i64], data: Vec<i32>) -> String {
        assert_eq!(dims.iter().product::<i64>() as usize, data.len(), "{hint}");
        let raw = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.tensor(hint, dims, INT32, raw)
    }

    fn op(&mut self, op: &str, inputs: &[&str], attrs: Vec<AttributeProto>) -> String {
        let out = self.name(&op.to_lowercase());
        let mut node = NodeProto::new();
        node.name = format!("{out}_node");
        node.op_type = op.into();
        node.input = inputs.iter().map(|s| s.to_string()).collect();
        node.output = vec![out.clone()];
        node.attribute = attrs;
        self.nodes.push(node);
        out
    }

    /// Renames the last node's output to `name`.
    fn rename_last_output(&mut self, name: &str) {
        if let Some(n) = self.nodes.last_mut() {
            n.output[0] = name.into();
        }
    }

    fn finish(self, size: usize, dim: usize, props: Vec<(String, String)>) -> Result<Vec<u8>> {
        let mut model = ModelProto::new();
        model.ir_version = 8;
        model.producer_name = "telextiles-lab".into();
        model.producer_version = env!("CARGO_PKG_VERSION").into();
        model.opset_import.push(Default::default());
        model.opset_import[0].version = OPSET;
        let g = model.graph.mut_or_insert_default();
        g.name = "telextiles_descriptor".into();
        g.node = self.nodes;
        g.initializer = self.inits;
        let value = |name: &str, dims: &[Option<i64>]| {
            let mut vi = onnx_ir::ValueInfoProto::new();
            vi.name = name.into();
            let tt = vi.type_.mut_or_insert_default().mut_tensor_type();
            tt.elem_type = FLOAT;
            let shape = tt.shape.mut_or_insert_default();
            for d in dims {
                shape.dim.push(Default::default());
                let last = shape.dim.last_mut().expect("just pushed");
                match d {
                    Some(v) => last.set_dim_value(*v),
                    None => last.set_dim_param("batch".into()),
                }
            }
            vi
        };
        let s = size as i64;
        g.input
            .push(value(INPUT_NAME, &[None, Some(3), Some(s), Some(s)]));
        g.output.push(value(OUTPUT_NAME, &[None, Some(dim as i64)]));
        for (k, v) in props {
            model.metadata_props.push(Default::default());
            let e = model.metadata_props.last_mut().expect("just pushed");
            e.key = k;
            e.value = v;
        }
        model.write_to_bytes().context("serialising ONNX")
    }
}

/// The DFT of `x` (`[N, C, n, n]`, real) on the half plane of row
/// frequencies 0..=n/2 and all column frequencies, as (real, imaginary)
/// parts `[N, C, n/2 + 1, n]`: two pairs of matrix products with fixed
/// cosine and sine matrices (`W = C - iS`, symmetric). Along rows first,
/// then along columns for the row frequencies 0..=n/2 only: the power
/// spectrum of a real image is point-symmetric, `P[ky, kx] = P[-ky, -kx]`.
fn half_plane_dft(b: &mut Builder, x: &str, n: usize) -> (String, String) {
    let ni = n as i64;
    let h = n / 2 + 1;
    let (mut cm, mut sm) = (vec![0f32; n * n], vec![0f32; n * n]);
    for k in 0..n {
        for j in 0..n {
            let a = 2.0 * PI * ((k * j) % n) as f64 / n as f64;
            cm[k * n + j] = a.cos() as f32;
            sm[k * n + j] = a.sin() as f32;
        }
    }
    let c = b.f32s("dft_cos", &[ni, ni], cm.clone());
    let s = b.f32s("dft_sin", &[ni, ni], sm.clone());
    let c_half = b.f32s("dft_cos_half", &[h as i64, ni], cm[..h * n].to_vec());
    let s_half = b.f32s("dft_sin_half", &[h as i64, ni], sm[..h * n].to_vec());
    let xc = b.op("MatMul", &[x, &c], vec![]);
    let xs = b.op("MatMul", &[x, &s], vec![]);
    let cxc = b.op("MatMul", &[&c_half, &xc], vec![]);
    let sxs = b.op("MatMul", &[&s_half, &xs], vec![]);
    let cxs = b.op("MatMul", &[&c_half, &xs], vec![]);
    let sxc = b.op("MatMul", &[&s_half, &xc], vec![]);
    let re = b.op("Sub", &[&cxc, &sxs], vec![]);
    let im = b.op("Add", &[&cxs, &sxc], vec![]);
    (re, im)
}

/// `x` (`[N, C, n, n]`) minus each image's mean per channel, times the 2D
/// Hann window, or the Tukey window of `taper` % ([`crate::wspec::tukey`])
/// below 100.
fn centred_windowed(b: &mut Builder, x: &str, n: usize, taper: u32) -> String {
    let hw = b.i64s("axes_hw", vec![2, 3]);
    let mean = b.op("ReduceMean", &[x, &hw], vec![attr_int("keepdims", 1)]);
    let centred = b.op("Sub", &[x, &mean], vec![]);
    // Tukey 1 is the Hann window; the Hann table stays as it was so that
    // every model exported before the taper writes the same bytes.
    let h: Vec<f32> = if taper >= 100 {
        hann(n)
    } else {
        crate::wspec::tukey(n, taper as f64 / 100.0)
            .into_iter()
            .map(|v| v as f32)
            .collect()
    };
    let win: Vec<f32> = (0..n * n).map(|i| h[i / n] * h[i % n]).collect();
    let win = b.f32s("hann2d", &[n as i64, n as i64], win);
    b.op("Mul", &[&centred, &win], vec![])
}

/// `x` (`[N, 3, n, n]`) minus each image's mean per channel, times a 2D
/// Hann window centred on the energy centroid of that difference
/// ([`crate::wspec::Window::Contact`]; [`crate::wspec::contact_centroid`]
/// and [`crate::wspec::hann_at`] are its reference).
fn contact_windowed(b: &mut Builder, x: &str, n: usize) -> String {
    let hw = b.i64s("axes_hw", vec![2, 3]);
    let mean = b.op("ReduceMean", &[x, &hw], vec![attr_int("keepdims", 1)]);
    let centred = b.op("Sub", &[x, &mean], vec![]);
    // Energy per pixel, summed over the channels: [N, 1, n, n].
    let sq = b.op("Mul", &[&centred, &centred], vec![]);
    let ax1 = b.i64s("axes_c", vec![1]);
    let energy = b.op("ReduceSum", &[&sq, &ax1], vec![attr_int("keepdims", 1)]);
    // Row and column profiles: [N, 1, n, 1] and [N, 1, 1, n].
    let ax3 = b.i64s("axes_w", vec![3]);
    let ax2 = b.i64s("axes_h", vec![2]);
    let rows = b.op("ReduceSum", &[&energy, &ax3], vec![attr_int("keepdims", 1)]);
    let cols = b.op("ReduceSum", &[&energy, &ax2], vec![attr_int("keepdims", 1)]);
    let total = b.op("ReduceSum", &[&rows, &ax2], vec![attr_int("keepdims", 1)]);
    let eps = crate::wspec::CENTROID_EPS;
    let eps_t = b.f32s("centroid_eps", &[1], vec![eps as f32]);
    let eps_c = b.f32s(
        "centroid_eps_centre",
        &[1],
        vec![(eps * n as f64 / 2.0) as f32],
    );
    let denom = b.op("Add", &[&total, &eps_t], vec![]);
    let half = b.f32s("half_n", &[1], vec![n as f32 / 2.0]);
    let k = b.f32s(
        "two_pi_over_n",
        &[1],
        vec![(2.0 * std::f64::consts::PI / n as f64) as f32],
    );
    let point_five = b.f32s("point_five", &[1], vec![0.5]);
    let idx: Vec<f32> = (0..n).map(|i| i as f32).collect();
    // One axis's window from its energy profile (`axis`: 2 rows, 3 columns).
    let window = |b: &mut Builder, profile: &str, dims: &[i64], axis: i64, hint: &str| {
        let grid = b.f32s(hint, dims, idx.clone());
        let moment = b.op("Mul", &[profile, &grid], vec![]);
        let ax = b.i64s("axes_moment", vec![axis]);
        let moment = b.op("ReduceSum", &[&moment, &ax], vec![attr_int("keepdims", 1)]);
        let moment = b.op("Add", &[&moment, &eps_c], vec![]);
        let centroid = b.op("Div", &[&moment, &denom], vec![]);
        // 0.5 + 0.5 cos(2π min(|i − c|, n/2) / n)
        let d = b.op("Sub", &[&grid, &centroid], vec![]);
        let d = b.op("Abs", &[&d], vec![]);
        let d = b.op("Min", &[&d, &half], vec![]);
        let a = b.op("Mul", &[&d, &k], vec![]);
        let c = b.op("Cos", &[&a], vec![]);
        let c = b.op("Mul", &[&c, &point_five], vec![]);
        b.op("Add", &[&c, &point_five], vec![])
    };
    let wy = window(b, &rows, &[n as i64, 1], 2, "grid_rows");
    let wx = window(b, &cols, &[1, n as i64], 3, "grid_cols");
    let win = b.op("Mul", &[&wy, &wx], vec![]);
    b.op("Mul", &[&centred, &win], vec![])
}

/// `[N, bins]`: for each row of `flat` (`[N, cells]`), the sum of
/// `weight[i] * flat[cells[i]]` per bin `bin[i]` (a gather and a
/// scatter-add, so no dense cells x bins matrix is stored).
fn scatter_bins(
    b: &mut Builder,
    flat: &str,
    (cells, bin, weight): (Vec<i32>, Vec<i32>, Vec<f32>),
    bin_hint: &str,
    bins: usize,
) -> String {
    let m = cells.len() as i64;
    let cells = b.i32s("bin_cells", &[m], cells);
    let gathered = b.op("Gather", &[flat, &cells], vec![attr_int("axis", 1)]);
    let weight = b.f32s("bin_weights", &[m], weight);
    let weighted = b.op("Mul", &[&gathered, &weight], vec![]);
    let bin = b.i32s(bin_hint, &[1, m], bin);
    let wshape = b.op("Shape", &[&weighted], vec![]);
    let bin = b.op("Expand", &[&bin, &wshape], vec![]);
    let (zero, one) = (b.i64s("zero", vec![0]), b.i64s("one", vec![1]));
    let batch = b.op("Slice", &[&wshape, &zero, &one], vec![]);
    let dims = b.i64s("bins_dim", vec![bins as i64]);
    let zshape = b.op("Concat", &[&batch, &dims], vec![attr_int("axis", 0)]);
    let zeros = b.op("ConstantOfShape", &[&zshape], vec![]);
    b.op(
        "ScatterElements",
        &[&zeros, &bin, &weighted],
        vec![attr_int("axis", 1), attr_str("reduction", "add")],
    )
}

/// The trained head on a descriptor's output `x` (`[N, input]`).
fn append_head(b: &mut Builder, x: &str, h: &MlpHead) -> String {
    let (i, hd, o) = (h.input as i64, h.hidden as i64, h.out as i64);
    let scale = b.f32s("head_scale", &[i], h.scale.clone());
    let x = b.op("Mul", &[x, &scale], vec![]);
    let first = h.first_width() as i64;
    let w1 = b.f32s("head_w1", &[i, first], h.w1.clone());
    let b1 = b.f32s("head_b1", &[first], h.b1.clone());
    let x = b.op("MatMul", &[&x, &w1], vec![]);
    let x = b.op("Add", &[&x, &b1], vec![]);
    if h.hidden == 0 {
        return x;
    }
    let x = b.op("Relu", &[&x], vec![]);
    let w2 = b.f32s("head_w2", &[hd, o], h.w2.clone());
    let b2 = b.f32s("head_b2", &[o], h.b2.clone());
    let x = b.op("MatMul", &[&x, &w2], vec![]);
    b.op("Add", &[&x, &b2], vec![])
}

/// The colour-whitened spectrum of the input (`[N, 3, n, n]`, the
/// normalised frame minus the normalised reference): radial log bins and
/// angular harmonics, `[N, wspec::dim(n)]`, as
/// [`crate::wspec::reference_with`] computes them with the same `window`.
fn wspec_graph(b: &mut Builder, n: usize, window: crate::wspec::Window, taper: u32) -> String {
    use crate::wspec::{self, BANDS, HARMONICS, SECTORS};
    let plane = (n * n) as i64;
    // Back to grey levels (the reference's offset is already gone).
    let w: Vec<f32> = (0..3).map(|c| 255.0 * DIGIT_STD[c]).collect();
    let w = b.f32s("dn_scale", &[1, 3, 1, 1], w);
    let x = b.op("Mul", &[INPUT_NAME, &w], vec![]);
    let xw = match window {
        crate::wspec::Window::Centre => centred_windowed(b, &x, n, taper),
        crate::wspec::Window::Contact => contact_windowed(b, &x, n),
    };
    // Colour covariance [N, 3, 3] of the windowed difference, with the ridge.
    let shape = b.i64s("chan_flat", vec![0, 3, plane]);
    let flat = b.op("Reshape", &[&xw, &shape], vec![]);
    let flat_t = b.op("Transpose", &[&flat], vec![attr_ints("perm", &[0, 2, 1])]);
    let gram = b.op("MatMul", &[&flat, &flat_t], vec![]);
    let inv_plane = b.f32s("inv_plane", &[1], vec![1.0 / (n * n) as f32]);
    let cov = b.op("Mul", &[&gram, &inv_plane], vec![]);
    let eye: Vec<f32> = (0..9).map(|i| if i % 4 == 0 { 1.0 } else { 0.0 }).collect();
    let eye = b.f32s("eye3", &[3, 3], eye);
    let diag = b.op("Mul", &[&cov, &eye], vec![]);
    let ax12 = b.i64s("axes_12", vec![1, 2]);
    let trace = b.op("ReduceSum", &[&diag, &ax12], vec![attr_int("keepdims", 1)]);
    let rel = b.f32s("ridge_rel", &[1], vec![(wspec::RIDGE_REL / 3.0) as f32]);
    let abs = b.f32s("ridge_abs", &[1], vec![wspec::RIDGE_ABS as f32]);
    let ridge = b.op("Mul", &[&trace, &rel], vec![]);
    let ridge = b.op("Add", &[&ridge, &abs], vec![]);
    let ridge = b.op("Mul", &[&ridge, &eye], vec![]);
    let cov = b.op("Add", &[&cov, &ridge], vec![]);
    // Its inverse: adjugate over determinant (symmetric 3x3).
    let nine = b.i64s("flat9", vec![-1, 9]);
    let c9 = b.op("Reshape", &[&cov, &nine], vec![]);
    let mut e = Vec::new();
    for k in [0i32, 1, 2, 4, 5, 8] {
        let idx = b.i32s("cov_entry", &[1], vec![k]);
        e.push(b.op("Gather", &[&c9, &idx], vec![attr_int("axis", 1)]));
    }
    let (a, bb, c, d, ee, f) = (&e[0], &e[1], &e[2], &e[3], &e[4], &e[5]);
    let mut minor = |p: &str, q: &str, r: &str, s: &str| {
        let pq = b.op("Mul", &[p, q], vec![]);
        let rs = b.op("Mul", &[r, s], vec![]);
        b.op("Sub", &[&pq, &rs], vec![])
    };
    let a00 = minor(d, f, ee, ee);
    let a01 = minor(c, ee, bb, f);
    let a02 = minor(bb, ee, c, d);
    let a11 = minor(a, f, c, c);
    let a12 = minor(bb, c, a, ee);
    let a22 = minor(a, d, bb, bb);
    let adj = b.op(
        "Concat",
        &[&a00, &a01, &a02, &a01, &a11, &a12, &a02, &a12, &a22],
        vec![attr_int("axis", 1)],
    );
    let t0 = b.op("Mul", &[a, &a00], vec![]);
    let t1 = b.op("Mul", &[bb, &a01], vec![]);
    let t2 = b.op("Mul", &[c, &a02], vec![]);
    let det = b.op("Add", &[&t0, &t1], vec![]);
    let det = b.op("Add", &[&det, &t2], vec![]);
    let inv = b.op("Div", &[&adj, &det], vec![]);
    let s33 = b.i64s("shape33", vec![-1, 3, 3]);
    let inv = b.op("Reshape", &[&inv, &s33], vec![]);
    // P(k) = F(k)^H inv F(k) / n^2 on the half plane.
    let (re, im) = half_plane_dft(b, &xw, n);
    let hn = ((n / 2 + 1) * n) as i64;
    let s3 = b.i64s("chan_half", vec![0, 3, hn]);
    let re = b.op("Reshape", &[&re, &s3], vec![]);
    let im = b.op("Reshape", &[&im, &s3], vec![]);
    let wre = b.op("MatMul", &[&inv, &re], vec![]);
    let wim = b.op("MatMul", &[&inv, &im], vec![]);
    let pr = b.op("Mul", &[&wre, &re], vec![]);
    let pi = b.op("Mul", &[&wim, &im], vec![]);
    let p = b.op("Add", &[&pr, &pi], vec![]);
    let ax1 = b.i64s("axes_1", vec![1]);
    let p = b.op("ReduceSum", &[&p, &ax1], vec![attr_int("keepdims", 0)]);
    let p = b.op("Mul", &[&p, &inv_plane], vec![]);
    // Radial log bins, their mean removed.
    let cells = wspec::cells(n);
    let (rw, aw) = wspec::bin_weights(n);
    let (mut ci, mut bi, mut wi) = (Vec::new(), Vec::new(), Vec::new());
    for cell in cells.iter().filter(|c| c.radial.is_some()) {
        ci.push(cell.cell as i32);
        bi.push(cell.radial.unwrap_or(0) as i32);
        wi.push(cell.weight as f32);
    }
    let nr = rw.len();
    let sums = scatter_bins(b, &p, (ci, bi, wi), "bin_radius", nr);
    let inv_w: Vec<f32> = rw.iter().map(|w| (1.0 / w) as f32).collect();
    let inv_w = b.f32s("radial_inv_weight", &[nr as i64], inv_w);
    let radial = b.op("Mul", &[&sums, &inv_w], vec![]);
    let eps = b.f32s("log_eps", &[1], vec![wspec::LOG_EPS as f32]);
    let radial = b.op("Add", &[&radial, &eps], vec![]);
    let log = b.op("Log", &[&radial], vec![]);
    let lmean = b.op("ReduceMean", &[&log, &ax1], vec![attr_int("keepdims", 1)]);
    let log = b.op("Sub", &[&log, &lmean], vec![]);
    // Angular profile per band, its harmonics' magnitudes over its total.
    let (mut ci, mut bi, mut wi) = (Vec::new(), Vec::new(), Vec::new());
    for cell in &cells {
        if let Some((band, sector)) = cell.angular {
            ci.push(cell.cell as i32);
            bi.push((band * SECTORS + sector) as i32);
            wi.push(cell.weight as f32);
        }
    }
    let sums = scatter_bins(b, &p, (ci, bi, wi), "bin_band_sector", BANDS * SECTORS);
    let inv_w: Vec<f32> = aw
        .iter()
        .map(|&w| if w > 0.0 { (1.0 / w) as f32 } else { 0.0 })
        .collect();
    let inv_w = b.f32s("angular_inv_weight", &[(BANDS * SECTORS) as i64], inv_w);
    let profile = b.op("Mul", &[&sums, &inv_w], vec![]);
    let sb = b.i64s("bands_sectors", vec![-1, BANDS as i64, SECTORS as i64]);
    let profile = b.op("Reshape", &[&profile, &sb], vec![]);
    let (mut hc, mut hs) = (Vec::new(), Vec::new());
    for s in 0..SECTORS {
        for m in 1..=HARMONICS {
            let t = -2.0 * PI * (m * s) as f64 / SECTORS as f64;
            hc.push(t.cos() as f32);
            hs.push(t.sin() as f32);
        }
    }
    let hc = b.f32s("harm_cos", &[SECTORS as i64, HARMONICS as i64], hc);
    let hs = b.f32s("harm_sin", &[SECTORS as i64, HARMONICS as i64], hs);
    let hr = b.op("MatMul", &[&profile, &hc], vec![]);
    let hi = b.op("MatMul", &[&profile, &hs], vec![]);
    let hr2 = b.op("Mul", &[&hr, &hr], vec![]);
    let hi2 = b.op("Mul", &[&hi, &hi], vec![]);
    let mag = b.op("Add", &[&hr2, &hi2], vec![]);
    let mag = b.op("Sqrt", &[&mag], vec![]);
    let ax2 = b.i64s("axes_2", vec![2]);
    let total = b.op(
        "ReduceSum",
        &[&profile, &ax2],
        vec![attr_int("keepdims", 1)],
    );
    let heps = b.f32s("harm_eps", &[1], vec![wspec::HARM_EPS as f32]);
    let total = b.op("Add", &[&total, &heps], vec![]);
    let harm = b.op("Div", &[&mag, &total], vec![]);
    let fh = b.i64s("harm_flat", vec![-1, (BANDS * HARMONICS) as i64]);
    let harm = b.op("Reshape", &[&harm, &fh], vec![]);
    b.op("Concat", &[&log, &harm], vec![attr_int("axis", 1)])
}

/// A fixed descriptor as an ONNX model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DescriptorSpec {
    /// `Fft` or `Pixels` (LBP has no graph).
    pub kind: BaselineKind,
    /// Centre crop of the frame (px).
    pub crop: u32,
    /// Side S of the input (even; crop == S: no resampling).
    pub input: u32,
    /// The model takes the frame minus the sensor's no-contact reference
    /// (`telextiles.background = subtract`). The graph is the same: the
    /// reference only removes what the mean subtraction and the window do
    /// not (the static LED pattern under the crop).
    pub subtract: bool,
    /// `fft`: the lowest radius bin kept (1: everything but DC; higher
    /// values drop the coarsest scales, where illumination gradients and
    /// the background's own pattern live).
    pub min_bin: u32,
    /// The window's taper in % (`fft`, `wspec`): 100 is the 2D Hann window
    /// every shipped descriptor uses; below, the flatter Tukey window
    /// ([`crate::wspec::tukey`]), named `-t<taper>` in the arch.
    pub taper: u32,
}

impl DescriptorSpec {
    /// `fft-radial-c64`, `pixels16-c64`.
    pub fn arch(&self) -> String {
        let k = match self.kind {
            BaselineKind::Fft => "fft-radial",
            BaselineKind::Pixels => "pixels16",
            BaselineKind::Lbp => "lbp-riu2",
            BaselineKind::WSpec => "wspec",
            BaselineKind::WSpecCw => "wspec-cw",
            BaselineKind::WSpecM(_) => "wspec-m",
            BaselineKind::MStats => "mstats",
        };
        let bg = if self.subtract { "-bg" } else { "" };
        let mut r = if self.kind == BaselineKind::Fft && self.min_bin > 1 {
            format!("-r{}", self.min_bin)
        } else {
            String::new()
        };
        if self.taper < 100 {
            r += &format!("-t{}", self.taper);
        }
        if self.crop == self.input {
            format!("{k}-c{}{r}{bg}", self.crop)
        } else {
            format!("{k}-c{}-s{}{r}{bg}", self.crop, self.input)
        }
    }

    /// Length of the descriptor.
    pub fn dim(&self) -> usize {
        match self.kind {
            BaselineKind::Fft => self.input as usize / 2 - self.min_bin.max(1) as usize,
            BaselineKind::Pixels => 16 * 16 * 3,
            BaselineKind::Lbp => 30,
            BaselineKind::WSpec | BaselineKind::WSpecCw => crate::wspec::dim(self.input as usize),
            BaselineKind::WSpecM(_) => crate::wspec::dim(self.input as usize) + crate::mstats::DIM,
            BaselineKind::MStats => crate::mstats::DIM,
        }
    }
}

/// The Hann window of length `n` (periodic, as `baselines.rs` uses it).
pub fn hann(n: usize) -> Vec<f32> {
    (0..n)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f32::consts::PI * i as f32 / n as f32).cos())
        .collect()
}

/// Writes `spec` as an ONNX model with the contract's metadata.
pub fn descriptor_model(spec: &DescriptorSpec) -> Result<Vec<u8>> {
    build_descriptor(spec, None, "none (fixed descriptor, not trained)")
}

/// A trained head on a descriptor's output: `y = W2 relu(W1 (x * scale) +
/// b1) + b2` (weights row-major `[in, out]`), or, with `hidden == 0`, the
/// linear map `y = W1 (x * scale) + b1` (`w1` is `[in, out]`, `w2` and `b2`
/// are empty).
#[derive(Clone, Debug, PartialEq)]
pub struct MlpHead {
    pub scale: Vec<f32>,
    pub w1: Vec<f32>,
    pub b1: Vec<f32>,
    pub w2: Vec<f32>,
    pub b2: Vec<f32>,
    pub input: usize,
    pub hidden: usize,
    pub out: usize,
}

impl MlpHead {
    /// `telextiles.arch` suffix: `+mlp<hidden>-<out>`.
    pub fn suffix(&self) -> String {
        if self.hidden == 0 {
            format!("+lin{}", self.out)
        } else {
            format!("+mlp{}-{}", self.hidden, self.out)
        }
    }

    /// Width of the first layer: the hidden layer's, or the output's for a
    /// linear head.
    fn first_width(&self) -> usize {
        if self.hidden == 0 {
            self.out
        } else {
            self.hidden
        }
    }

    /// Whether the shapes fit an `input`-long descriptor.
    fn fits(&self, input: usize) -> bool {
        let first = self.first_width();
        let (w2, b2) = if self.hidden == 0 {
            (0, 0)
        } else {
            (self.hidden * self.out, self.out)
        };
        self.input == input
            && self.scale.len() == input
            && self.w1.len() == input * first
            && self.b1.len() == first
            && self.w2.len() == w2
            && self.b2.len() == b2
    }
}

/// The trained head of a model written by [`descriptor_with_head`], read
/// back from its initialisers, with its `telextiles.train_data_hash`
/// (`None`: the model has no head). Rebuilding the model from the spec,
/// this head and this hash gives the same bytes for a model this builder
/// wrote, which is how the shipped model's provenance is checked.
pub fn read_head(model: &[u8]) -> Result<Option<(MlpHead, String)>> {
    let m = ModelProto::parse_from_bytes(model).context("not an ONNX model")?;
    let g = m.graph.as_ref().context("the model has no graph")?;
    let find = |prefix: &str| -> Option<(Vec<f32>, Vec<i64>)> {
        let t = g.initializer.iter().find(|t| {
            t.name
                .strip_prefix(prefix)
                .is_some_and(|rest| rest.chars().all(|c| c.is_ascii_digit()))
        })?;
        let v = t
            .raw_data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        Some((v, t.dims.clone()))
    };
    let Some((scale, _)) = find("head_scale_") else {
        return Ok(None);
    };
    let (w1, d1) = find("head_w1_").context("head_scale without head_w1")?;
    let (b1, _) = find("head_b1_").context("head_scale without head_b1")?;
    let second = find("head_w2_");
    let (w2, b2, hidden, out) = match second {
        Some((w2, d2)) => {
            let (b2, _) = find("head_b2_").context("head_w2 without head_b2")?;
            (
                w2,
                b2,
                *d1.get(1).context("head_w1 is not 2-d")? as usize,
                *d2.get(1).context("head_w2 is not 2-d")? as usize,
            )
        }
        None => (
            Vec::new(),
            Vec::new(),
            0,
            *d1.get(1).context("head_w1 is not 2-d")? as usize,
        ),
    };
    let hash = m
        .metadata_props
        .iter()
        .find(|p| p.key == "telextiles.train_data_hash")
        .map(|p| p.value.clone())
        .unwrap_or_default();
    Ok(Some((
        MlpHead {
            input: scale.len(),
            scale,
            w1,
            b1,
            w2,
            b2,
            hidden,
            out,
        },
        hash,
    )))
}

/// The `fft` descriptor followed by a trained head, as one ONNX model with
/// the encoder contract (the head's training-data hash in the metadata).
pub fn descriptor_with_head(
    spec: &DescriptorSpec,
    head: &MlpHead,
    train_hash: &str,
) -> Result<Vec<u8>> {
    ensure!(
        matches!(
            spec.kind,
            BaselineKind::Fft | BaselineKind::WSpec | BaselineKind::WSpecCw
        ),
        "a head goes on the fft or wspec descriptor"
    );
    ensure!(
        head.fits(spec.dim()),
        "the head's shapes do not fit a {}-d descriptor",
        spec.dim()
    );
    build_descriptor(spec, Some(head), train_hash)
}

fn build_descriptor(
    spec: &DescriptorSpec,
    head: Option<&MlpHead>,
    train_hash: &str,
) -> Result<Vec<u8>> {
    let n = spec.input as usize;
    ensure!(
        n.is_multiple_of(2) && (16..=240).contains(&n),
        "descriptor input size {n} must be even, in 16..=240"
    );
    ensure!(
        spec.min_bin >= 1 && (spec.min_bin as usize) < n / 4,
        "min_bin {} must be in 1..{}",
        spec.min_bin,
        n / 4
    );
    ensure!(
        (1..=100).contains(&spec.taper),
        "taper {} % must be in 1..=100 (100: the Hann window)",
        spec.taper
    );
    ensure!(
        spec.crop >= spec.input && spec.crop <= 240,
        "crop {} must be in input size..=240",
        spec.crop
    );
    let mut b = Builder::default();
    let dim = spec.dim();
    match spec.kind {
        BaselineKind::Fft => {
            // grey = sum_c g_c * 255 * (x_c * std_c + mean_c): a 1x1 convolution.
            let w: Vec<f32> = (0..3).map(|c| GREY[c] * 255.0 * DIGIT_STD[c]).collect();
            let bias: f32 = (0..3).map(|c| GREY[c] * 255.0 * DIGIT_MEAN[c]).sum();
            let w = b.f32s("grey_w", &[1, 3, 1, 1], w);
            let bias = b.f32s("grey_b", &[1], vec![bias]);
            let grey = b.op("Conv", &[INPUT_NAME, &w, &bias], vec![]);
            let x = centred_windowed(&mut b, &grey, n, spec.taper);
            let (re, im) = half_plane_dft(&mut b, &x, n);
            let re2 = b.op("Mul", &[&re, &re], vec![]);
            let im2 = b.op("Mul", &[&im, &im], vec![]);
            let power = b.op("Add", &[&re2, &im2], vec![]);
            let h = n / 2 + 1;
            let shape = b.i64s("flat_shape", vec![-1, (h * n) as i64]);
            let flat = b.op("Reshape", &[&power, &shape], vec![]);
            // Radial mean over bins 1..n/2: gather the half-plane cells of
            // each bin, weight the rows that stand for their mirror too (all
            // but ky = 0 and n/2) by 2, sum per bin (scatter-add), divide by
            // the bin's full-plane cell count.
            let (_, counts) = radial_bins(n);
            let r0 = spec.min_bin.max(1) as usize;
            let (mut cells, mut radius, mut weight) = (Vec::new(), Vec::new(), Vec::new());
            for (cell, r) in half_plane_bins(n).into_iter().filter(|&(_, r)| r >= r0) {
                cells.push(cell as i32);
                radius.push((r - r0) as i32);
                weight.push(if cell / n == 0 || cell / n == n / 2 {
                    1.0
                } else {
                    2.0
                });
            }
            let sums = scatter_bins(&mut b, &flat, (cells, radius, weight), "bin_radius", dim);
            let inv: Vec<f32> = (r0..r0 + dim).map(|r| 1.0 / counts[r] as f32).collect();
            let inv = b.f32s("bin_inv_count", &[dim as i64], inv);
            let radial = b.op("Mul", &[&sums, &inv], vec![]);
            let eps = b.f32s("log_eps", &[1], vec![1e-3]);
            let shifted = b.op("Add", &[&radial, &eps], vec![]);
            let log = b.op("Log", &[&shifted], vec![]);
            let ax1 = b.i64s("axes_1", vec![1]);
            let lmean = b.op("ReduceMean", &[&log, &ax1], vec![attr_int("keepdims", 1)]);
            let spectrum = b.op("Sub", &[&log, &lmean], vec![]);
            if let Some(h) = head {
                append_head(&mut b, &spectrum, h);
            }
            b.rename_last_output(OUTPUT_NAME);
        }
        BaselineKind::WSpec | BaselineKind::WSpecCw => {
            ensure!(
                spec.subtract,
                "wspec is defined on frame minus reference: export it with the reference subtracted"
            );
            let window = spec.kind.wspec_window().expect("a wspec kind");
            ensure!(
                spec.taper >= 100 || window == crate::wspec::Window::Centre,
                "a window on the contact is a Hann window: taper {} is for the centred window",
                spec.taper
            );
            let spectrum = wspec_graph(&mut b, n, window, spec.taper);
            if let Some(h) = head {
                append_head(&mut b, &spectrum, h);
            }
            b.rename_last_output(OUTPUT_NAME);
        }
        BaselineKind::Pixels => {
            ensure!(
                n.is_multiple_of(16),
                "pixels needs an input size divisible by 16"
            );
            // Back to 0..255 per channel (a depthwise 1x1 convolution).
            let w: Vec<f32> = (0..3).map(|c| 255.0 * DIGIT_STD[c]).collect();
            let bias: Vec<f32> = (0..3).map(|c| 255.0 * DIGIT_MEAN[c]).collect();
            let w = b.f32s("unnorm_w", &[3, 1, 1, 1], w);
            let bias = b.f32s("unnorm_b", &[3], bias);
            let rgb = b.op("Conv", &[INPUT_NAME, &w, &bias], vec![attr_int("group", 3)]);
            let k = (n / 16) as i64;
            let pooled = b.op(
                "AveragePool",
                &[&rgb],
                vec![
                    attr_ints("kernel_shape", &[k, k]),
                    attr_ints("strides", &[k, k]),
                ],
            );
            let hw = b.i64s("axes_hw", vec![2, 3]);
            let mean = b.op("ReduceMean", &[&pooled, &hw], vec![attr_int("keepdims", 1)]);
            let centred = b.op("Sub", &[&pooled, &mean], vec![]);
            let shape = b.i64s("flat_shape", vec![-1, dim as i64]);
            b.op("Reshape", &[&centred, &shape], vec![]);
            b.rename_last_output(OUTPUT_NAME);
        }
        BaselineKind::Lbp => anyhow::bail!("LBP has no ONNX graph"),
        BaselineKind::WSpecM(_) | BaselineKind::MStats => {
            anyhow::bail!("the marginal statistics have no ONNX graph yet")
        }
    }
    let (dim, arch) = match head {
        Some(h) => (h.out, format!("{}{}", spec.arch(), h.suffix())),
        None => (dim, spec.arch()),
    };
    let props = contract_props(spec.input, spec.crop, dim, &arch, train_hash, spec.subtract);
    b.finish(n, dim, props)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::baselines::Baseline;
    use crate::ortrun::OrtEncoder;
    use crate::preprocess::normalize_into;

    fn l2(mut v: Vec<f32>) -> Vec<f32> {
        crate::knn::l2(&mut v);
        v
    }

    /// Pseudo-random textured RGB images of side `n`.
    fn images(n: usize, count: usize) -> Vec<Vec<u8>> {
        (0..count)
            .map(|k| {
                (0..n * n * 3)
                    .map(|i| {
                        let (x, y, c) = ((i / 3) % n, (i / 3) / n, i % 3);
                        let v = 120.0
                            + 50.0 * ((x as f32 * (0.3 + 0.1 * k as f32)) + y as f32 * 0.7).sin()
                            + 20.0 * c as f32
                            + ((i * 7919 + k * 104_729) % 13) as f32;
                        v.clamp(0.0, 255.0) as u8
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn graphs_match_the_rust_descriptors_in_onnx_runtime() {
        for (kind, n) in [
            (BaselineKind::Fft, 64usize),
            (BaselineKind::Fft, 32),
            (BaselineKind::Pixels, 64),
        ] {
            let spec = DescriptorSpec {
                kind,
                crop: n as u32,
                input: n as u32,
                subtract: false,
                min_bin: 1,
                taper: 100,
            };
            let bytes = descriptor_model(&spec).unwrap();
            let mut enc = OrtEncoder::from_bytes(&bytes, 1).unwrap();
            assert_eq!(enc.dim, spec.dim());
            assert_eq!(enc.input_size, n);
            let imgs = images(n, 3);
            let mut x = Vec::new();
            for img in &imgs {
                normalize_into(img, n, &mut x);
            }
            let got = enc.embed(&x).unwrap();
            let base = Baseline { kind, bgsub: false };
            for (i, img) in imgs.iter().enumerate() {
                let want = base.features(img, n, n, None);
                let g = l2(got[i * spec.dim()..(i + 1) * spec.dim()].to_vec());
                let diff = g
                    .iter()
                    .zip(&want)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0f32, f32::max);
                // The graph's DFT is f32 matrix products; the Rust reference
                // is an f64 FFT. A pure grating over faint noise (these
                // images) spans the most decades: 4e-4 on one log bin.
                assert!(diff < 1e-3, "{kind:?} n={n} image {i}: max diff {diff}");
            }
            // A blank frame gives finite numbers (the daemon's dry run).
            let blank = vec![0f32; 3 * n * n];
            assert!(enc.embed(&blank).unwrap().iter().all(|v| v.is_finite()));
        }
    }

    /// The descriptor by direct f64 DFT (any even n): the reference for
    /// sizes the Rust FFT does not take.
    fn radial_reference(grey: &[f64], n: usize, r0: usize) -> Vec<f32> {
        let mean = grey.iter().sum::<f64>() / grey.len() as f64;
        let h = hann(n);
        let x: Vec<f64> = (0..n * n)
            .map(|i| (grey[i] - mean) * h[i / n] as f64 * h[i % n] as f64)
            .collect();
        let (cells, cnt) = radial_bins(n);
        let mut sum = vec![0f64; n / 2];
        for &(cell, r) in &cells {
            let (ky, kx) = (cell / n, cell % n);
            let (mut re, mut im) = (0f64, 0f64);
            for y in 0..n {
                for xx in 0..n {
                    let a = -2.0 * PI * (((ky * y) % n) as f64 + ((kx * xx) % n) as f64) / n as f64;
                    re += x[y * n + xx] * a.cos();
                    im += x[y * n + xx] * a.sin();
                }
            }
            sum[r] += re * re + im * im;
        }
        let f: Vec<f64> = (r0..n / 2)
            .map(|r| (sum[r] / cnt[r] as f64 + 1e-3).ln())
            .collect();
        let m = f.iter().sum::<f64>() / f.len() as f64;
        l2(f.iter().map(|v| (v - m) as f32).collect())
    }

    fn grey_of(img: &[u8]) -> Vec<f64> {
        img.chunks(3)
            .map(|p| (0..3).map(|c| GREY[c] as f64 * p[c] as f64).sum())
            .collect()
    }

    #[test]
    fn any_even_size_and_background_subtraction_match_references() {
        // 48 is no power of two: against the direct f64 DFT.
        let n = 48;
        let spec = DescriptorSpec {
            kind: BaselineKind::Fft,
            crop: 48,
            input: 48,
            subtract: false,
            min_bin: 1,
            taper: 100,
        };
        let mut enc = OrtEncoder::from_bytes(&descriptor_model(&spec).unwrap(), 1).unwrap();
        let imgs = images(n, 2);
        for img in &imgs {
            let mut x = Vec::new();
            normalize_into(img, n, &mut x);
            let got = l2(enc.embed(&x).unwrap());
            let want = radial_reference(&grey_of(img), n, 1);
            let d = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            assert!(d < 1e-3, "n=48: max diff {d}");
        }
        // Dropping the coarsest bins (min_bin 4): bins 4..24, centred anew.
        let spec = DescriptorSpec { min_bin: 4, ..spec };
        assert_eq!(spec.arch(), "fft-radial-c48-r4");
        let mut enc = OrtEncoder::from_bytes(&descriptor_model(&spec).unwrap(), 1).unwrap();
        assert_eq!(enc.dim, 20);
        let mut x = Vec::new();
        normalize_into(&imgs[0], n, &mut x);
        let got = l2(enc.embed(&x).unwrap());
        let want = radial_reference(&grey_of(&imgs[0]), n, 4);
        let d = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(d < 1e-3, "min_bin 4: max diff {d}");
        // Background subtraction: the model fed normalise(frame) -
        // normalise(reference) computes the descriptor of frame - reference,
        // as the Rust descriptor with bgsub does.
        let n = 64;
        let spec = DescriptorSpec {
            kind: BaselineKind::Fft,
            crop: 64,
            input: 64,
            subtract: true,
            min_bin: 1,
            taper: 100,
        };
        let mut enc = OrtEncoder::from_bytes(&descriptor_model(&spec).unwrap(), 1).unwrap();
        let imgs = images(n, 2);
        let (frame, reference) = (&imgs[0], &imgs[1]);
        let mut x = Vec::new();
        crate::preprocess::input_into(frame, Some(reference), n, &mut x);
        let got = l2(enc.embed(&x).unwrap());
        let want = Baseline {
            kind: BaselineKind::Fft,
            bgsub: true,
        }
        .features(frame, n, n, Some(reference));
        let d = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(d < 1e-3, "subtract: max diff {d}");
    }

    #[test]
    fn a_head_on_the_descriptor_computes_the_mlp_of_its_spectrum() {
        let spec = DescriptorSpec {
            kind: BaselineKind::Fft,
            crop: 32,
            input: 32,
            subtract: true,
            min_bin: 1,
            taper: 100,
        };
        let (i, h, o) = (spec.dim(), 8, 5);
        let w = |n: usize, k: usize| -> Vec<f32> {
            (0..n)
                .map(|j| ((j * 31 + k) % 17) as f32 / 17.0 - 0.45)
                .collect()
        };
        let head = MlpHead {
            scale: w(i, 1).iter().map(|v| v + 1.0).collect(),
            w1: w(i * h, 2),
            b1: w(h, 3),
            w2: w(h * o, 4),
            b2: w(o, 5),
            input: i,
            hidden: h,
            out: o,
        };
        let bytes = descriptor_with_head(&spec, &head, "test").unwrap();
        let mut enc = OrtEncoder::from_bytes(&bytes, 1).unwrap();
        assert_eq!(enc.dim, o);
        assert_eq!(
            enc.meta.get("telextiles.arch").map(String::as_str),
            Some("fft-radial-c32-bg+mlp8-5")
        );
        let mut front = OrtEncoder::from_bytes(&descriptor_model(&spec).unwrap(), 1).unwrap();
        let imgs = images(32, 2);
        let mut x = Vec::new();
        crate::preprocess::input_into(&imgs[0], Some(&imgs[1]), 32, &mut x);
        let got = enc.embed(&x).unwrap();
        let spectrum = front.embed(&x).unwrap();
        let hidden: Vec<f32> = (0..h)
            .map(|k| {
                let v: f32 = (0..i)
                    .map(|j| spectrum[j] * head.scale[j] * head.w1[j * h + k])
                    .sum::<f32>()
                    + head.b1[k];
                v.max(0.0)
            })
            .collect();
        for (k, g) in got.iter().enumerate().take(o) {
            let want: f32 =
                (0..h).map(|j| hidden[j] * head.w2[j * o + k]).sum::<f32>() + head.b2[k];
            assert!((g - want).abs() < 1e-3, "output {k}: {g} vs {want}");
        }
        // Shapes that do not fit are refused.
        let mut bad = head.clone();
        bad.b1.pop();
        assert!(descriptor_with_head(&spec, &bad, "test").is_err());
    }

    #[test]
    fn wspec_graph_computes_its_reference_with_and_without_a_linear_head() {
        let n = 32;
        let spec = wspec_64_to_32(100);
        assert_eq!(spec.arch(), "wspec-c64-s32-bg");
        let imgs = images(n, 3);
        let (x, mut enc) = wspec_matches_reference(&spec, &imgs, crate::wspec::Window::Centre);
        assert_eq!(enc.meta["telextiles.background"], "subtract");
        let got = enc.embed(&x).unwrap();
        let d = spec.dim();
        // A frame equal to its reference: zeros, not NaN.
        let mut blank = Vec::new();
        crate::preprocess::input_into(&imgs[0], Some(&imgs[0]), n, &mut blank);
        assert!(enc.embed(&blank).unwrap().iter().all(|v| *v == 0.0));
        // A linear head: y = W (x * scale) + b.
        let o = 6;
        let head = MlpHead {
            scale: (0..d).map(|j| 1.0 + (j % 5) as f32 * 0.1).collect(),
            w1: (0..d * o)
                .map(|j| ((j * 13) % 7) as f32 / 7.0 - 0.4)
                .collect(),
            b1: (0..o).map(|j| j as f32 * 0.01).collect(),
            w2: Vec::new(),
            b2: Vec::new(),
            input: d,
            hidden: 0,
            out: o,
        };
        let bytes = descriptor_with_head(&spec, &head, "test").unwrap();
        let mut lin = OrtEncoder::from_bytes(&bytes, 1).unwrap();
        assert_eq!(lin.dim, o);
        assert_eq!(lin.meta["telextiles.arch"], "wspec-c64-s32-bg+lin6");
        let y = lin.embed(&x[..3 * n * n]).unwrap();
        for (k, g) in y.iter().enumerate() {
            let want: f32 = (0..d)
                .map(|j| got[j] * head.scale[j] * head.w1[j * o + k])
                .sum::<f32>()
                + head.b1[k];
            assert!((g - want).abs() < 1e-3, "output {k}: {g} vs {want}");
        }
        // wspec is defined on frame minus reference only.
        let raw = DescriptorSpec {
            subtract: false,
            ..spec
        };
        assert!(descriptor_model(&raw).is_err());
    }

    /// `a − b` (HWC u8 images of side `n`) as planar `[3][n][n]` f64.
    fn planar_diff(a: &[u8], b: &[u8], n: usize) -> Vec<f64> {
        let plane = n * n;
        let mut diff = vec![0f64; 3 * plane];
        for i in 0..plane {
            for c in 0..3 {
                diff[c * plane + i] = a[i * 3 + c] as f64 - b[i * 3 + c] as f64;
            }
        }
        diff
    }

    /// Runs `spec`'s graph on frame 0 − frame 1 and frame 2 − frame 0 of
    /// `imgs` and checks it against the f64 reference with `window`;
    /// returns the two inputs and the loaded graph.
    fn wspec_matches_reference(
        spec: &DescriptorSpec,
        imgs: &[Vec<u8>],
        window: crate::wspec::Window,
    ) -> (Vec<f32>, OrtEncoder) {
        let n = spec.input as usize;
        let bytes = descriptor_model(spec).unwrap();
        let mut enc = OrtEncoder::from_bytes(&bytes, 1).unwrap();
        assert_eq!(enc.dim, crate::wspec::dim(n));
        let pairs = [(0, 1), (2, 0)];
        let mut x = Vec::new();
        for pair in pairs {
            crate::preprocess::input_into(&imgs[pair.0], Some(&imgs[pair.1]), n, &mut x);
        }
        let got = enc.embed(&x).unwrap();
        let d = spec.dim();
        for (k, pair) in pairs.into_iter().enumerate() {
            let diff = planar_diff(&imgs[pair.0], &imgs[pair.1], n);
            let want = crate::wspec::reference_tapered(&diff, n, window, spec.taper as f64 / 100.0);
            let err = got[k * d..(k + 1) * d]
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            assert!(err < 2e-3, "{}, frame {k}: max diff {err}", spec.arch());
        }
        (x, enc)
    }

    /// `wspec` of the 64-px crop at 32 px under a window of `taper` %.
    fn wspec_64_to_32(taper: u32) -> DescriptorSpec {
        DescriptorSpec {
            kind: BaselineKind::WSpec,
            crop: 64,
            input: 32,
            subtract: true,
            min_bin: 1,
            taper,
        }
    }

    /// A Tukey window (`--taper 50`): the graph computes the f64 reference
    /// under the same window, is named for it, differs from the Hann
    /// window's, and is refused on the contact window and outside 1..=100.
    #[test]
    fn a_tapered_wspec_graph_computes_its_reference() {
        let n = 32;
        let spec = wspec_64_to_32(50);
        assert_eq!(spec.arch(), "wspec-c64-s32-t50-bg");
        let imgs = images(n, 3);
        let (x, mut enc) = wspec_matches_reference(&spec, &imgs, crate::wspec::Window::Centre);
        assert_eq!(enc.meta["telextiles.arch"], "wspec-c64-s32-t50-bg");
        let tapered = enc.embed(&x).unwrap();
        let hann = DescriptorSpec { taper: 100, ..spec };
        let mut h = OrtEncoder::from_bytes(&descriptor_model(&hann).unwrap(), 1).unwrap();
        let plain = h.embed(&x).unwrap();
        let diff = tapered
            .iter()
            .zip(&plain)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(diff > 1e-2, "the window changed nothing: {diff}");
        for (kind, taper) in [
            (BaselineKind::WSpecCw, 50),
            (BaselineKind::WSpec, 0),
            (BaselineKind::WSpec, 101),
        ] {
            let e = descriptor_model(&DescriptorSpec {
                kind,
                taper,
                ..spec
            })
            .unwrap_err();
            assert!(e.to_string().contains("taper"), "{e}");
        }
    }

    #[test]
    fn the_contact_window_graph_computes_its_reference() {
        let n = 32;
        let spec = DescriptorSpec {
            kind: BaselineKind::WSpecCw,
            crop: 64,
            input: n as u32,
            subtract: true,
            min_bin: 1,
            taper: 100,
        };
        assert_eq!(spec.arch(), "wspec-cw-c64-s32-bg");
        // Whole-frame differences, and a contact in one corner (frame 0
        // differs from frame 1 only there), so the window moves far.
        let mut imgs = images(n, 3);
        wspec_matches_reference(&spec, &imgs, crate::wspec::Window::Contact);
        let plane = n * n;
        for i in 0..plane {
            let (y, x) = (i / n, i % n);
            if y >= 10 || x >= 12 {
                for c in 0..3 {
                    imgs[1][i * 3 + c] = imgs[0][i * 3 + c];
                }
            }
        }
        let (x, mut enc) = wspec_matches_reference(&spec, &imgs, crate::wspec::Window::Contact);
        let centred = crate::wspec::centred(&planar_diff(&imgs[0], &imgs[1], n), n);
        let (cy, cx) = crate::wspec::contact_centroid(&centred, n);
        assert!(cy < 9.0 && cx < 10.0, "centroid ({cy}, {cx})");
        // A blank difference: zeros, as with the centred window.
        assert!(enc.embed(&x).unwrap().iter().all(|v| v.is_finite()));
        let mut blank = Vec::new();
        crate::preprocess::input_into(&imgs[0], Some(&imgs[0]), n, &mut blank);
        assert!(enc.embed(&blank).unwrap().iter().all(|v| *v == 0.0));
    }

    #[test]
    fn a_head_reads_back_and_rebuilds_the_same_bytes() {
        for (kind, crop, input, hidden) in [
            (BaselineKind::WSpec, 64, 32, 0),
            (BaselineKind::Fft, 32, 32, 4),
        ] {
            let spec = DescriptorSpec {
                kind,
                crop,
                input,
                subtract: true,
                min_bin: 1,
                taper: 100,
            };
            let (i, o) = (spec.dim(), 3);
            let first = if hidden == 0 { o } else { hidden };
            let v = |n: usize, k: usize| -> Vec<f32> {
                (0..n).map(|j| ((j * 7 + k) % 11) as f32 / 11.0).collect()
            };
            let head = MlpHead {
                scale: v(i, 1),
                w1: v(i * first, 2),
                b1: v(first, 3),
                w2: if hidden == 0 {
                    Vec::new()
                } else {
                    v(hidden * o, 4)
                },
                b2: if hidden == 0 { Vec::new() } else { v(o, 5) },
                input: i,
                hidden,
                out: o,
            };
            let bytes = descriptor_with_head(&spec, &head, "abc123").unwrap();
            let (back, hash) = read_head(&bytes).unwrap().expect("a head");
            assert_eq!(back, head);
            assert_eq!(hash, "abc123");
            assert_eq!(descriptor_with_head(&spec, &back, &hash).unwrap(), bytes);
        }
        // A descriptor without a head has none.
        let plain = descriptor_model(&DescriptorSpec {
            kind: BaselineKind::Fft,
            crop: 32,
            input: 32,
            subtract: true,
            min_bin: 1,
            taper: 100,
        })
        .unwrap();
        assert!(read_head(&plain).unwrap().is_none());
        assert!(read_head(b"not onnx").is_err());
    }

    #[test]
    fn bad_specs_are_refused() {
        let spec = |kind, crop, input| DescriptorSpec {
            kind,
            crop,
            input,
            subtract: false,
            min_bin: 1,
            taper: 100,
        };
        let e = descriptor_model(&spec(BaselineKind::Fft, 64, 47)).unwrap_err();
        assert!(e.to_string().contains("even"), "{e}");
        assert!(descriptor_model(&spec(BaselineKind::Fft, 300, 64)).is_err());
        assert!(descriptor_model(&spec(BaselineKind::Lbp, 64, 64)).is_err());
        // Any even size works for the matrix DFT (the crop need not be a
        // power of two), and background subtraction is declared.
        let bytes = descriptor_model(&DescriptorSpec {
            subtract: true,
            min_bin: 1,
            ..spec(BaselineKind::Fft, 96, 96)
        })
        .unwrap();
        let enc = OrtEncoder::from_bytes(&bytes, 1).unwrap();
        assert_eq!(enc.dim, 47);
        assert_eq!(enc.meta["telextiles.background"], "subtract");
        assert_eq!(enc.meta["telextiles.arch"], "fft-radial-c96-bg");
    }
}
