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
mod tests;
