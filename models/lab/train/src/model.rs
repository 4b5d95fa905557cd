//! The encoder family: configurable ResNets (ResNet-18 as in the paper, and
//! smaller depth/width/input-size variants) plus the MoCo projection head.
//!
//! Only [`Encoder`] is exported to ONNX; the projection head exists for
//! training only (as in MoCo v2 / SimCLR).

use anyhow::{bail, Context};
use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig, MaxPool2d, MaxPool2dConfig};
use burn::nn::{BatchNorm, BatchNormConfig, Linear, LinearConfig, PaddingConfig2d};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};

/// Architecture of one encoder. `name()` is what goes into the ONNX
/// metadata key `telextiles.arch` and `parse` reads it back.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ArchConfig {
    /// Basic blocks per stage (ResNet-18: `[2, 2, 2, 2]`).
    pub blocks: [usize; 4],
    /// Channels of the first stage; stages have `w, 2w, 4w, 8w` (ResNet-18: 64).
    pub width: usize,
    /// Side of the square network input in pixels (paper: 224).
    pub input: usize,
    /// Optional linear layer after global pooling giving this many dims;
    /// `None` means the pooled `8 * width` features are the embedding.
    pub embed_dim: Option<usize>,
}

impl ArchConfig {
    /// The paper's encoder: ResNet-18, 224x224 input, 512-d.
    pub fn resnet18() -> Self {
        ArchConfig {
            blocks: [2, 2, 2, 2],
            width: 64,
            input: 224,
            embed_dim: None,
        }
    }

    /// Width of the pooled backbone features.
    pub fn feature_dim(&self) -> usize {
        8 * self.width
    }

    /// Dimension of the exported embedding.
    pub fn embedding_dim(&self) -> usize {
        self.embed_dim.unwrap_or_else(|| self.feature_dim())
    }

    /// Canonical name, e.g. `resnet18-w64-s224` or `resnet-d1111-w16-s64`
    /// (`-e<dim>` appended when an embedding layer is present).
    pub fn name(&self) -> String {
        let depth = if self.blocks == [2, 2, 2, 2] {
            "resnet18".to_string()
        } else {
            format!(
                "resnet-d{}{}{}{}",
                self.blocks[0], self.blocks[1], self.blocks[2], self.blocks[3]
            )
        };
        let mut s = format!("{depth}-w{}-s{}", self.width, self.input);
        if let Some(e) = self.embed_dim {
            s.push_str(&format!("-e{e}"));
        }
        s
    }

    /// Parse a name written by [`ArchConfig::name`].
    pub fn parse(name: &str) -> anyhow::Result<Self> {
        let mut parts = name.split('-');
        let first = parts.next().unwrap_or_default();
        let blocks = match first {
            "resnet18" => [2, 2, 2, 2],
            "resnet" => {
                let d = parts
                    .next()
                    .and_then(|d| d.strip_prefix('d'))
                    .with_context(|| format!("arch {name:?}: expected resnet-dXXXX-..."))?;
                let digits: Vec<usize> = d
                    .chars()
                    .map(|c| c.to_digit(10).map(|v| v as usize))
                    .collect::<Option<_>>()
                    .with_context(|| format!("arch {name:?}: depth {d:?} is not 4 digits"))?;
                if digits.len() != 4 || digits.contains(&0) {
                    bail!("arch {name:?}: depth must be 4 digits 1-9, e.g. d1111");
                }
                [digits[0], digits[1], digits[2], digits[3]]
            }
            _ => bail!("arch {name:?}: must start with resnet18- or resnet-d"),
        };
        let (mut width, mut input, mut embed_dim) = (None, None, None);
        for p in parts {
            let (key, val) = p.split_at(1.min(p.len()));
            let v: usize = val
                .parse()
                .with_context(|| format!("arch {name:?}: bad number in {p:?}"))?;
            match key {
                "w" => width = Some(v),
                "s" => input = Some(v),
                "e" => embed_dim = Some(v),
                _ => bail!("arch {name:?}: unknown part {p:?} (w<width>, s<input>, e<dim>)"),
            }
        }
        let cfg = ArchConfig {
            blocks,
            width: width.with_context(|| format!("arch {name:?}: missing -w<width>"))?,
            input: input.with_context(|| format!("arch {name:?}: missing -s<input>"))?,
            embed_dim,
        };
        if cfg.width == 0 || cfg.input < 32 || cfg.embed_dim == Some(0) {
            bail!("arch {name:?}: width must be >0, input >=32, embedding >0");
        }
        Ok(cfg)
    }

    /// Build a freshly initialised encoder.
    pub fn init_encoder(&self, device: &Device) -> Encoder {
        let w = self.width;
        let stem = Conv2dConfig::new([3, w], [7, 7])
            .with_stride([2, 2])
            .with_padding(PaddingConfig2d::Explicit(3, 3, 3, 3))
            .with_bias(false)
            .init(device);
        let stem_bn = BatchNormConfig::new(w).init(device);
        let pool = MaxPool2dConfig::new([3, 3])
            .with_strides([2, 2])
            .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
            .init();
        let mut blocks = Vec::new();
        let mut cin = w;
        for (stage, &n) in self.blocks.iter().enumerate() {
            let cout = w << stage;
            for b in 0..n {
                let stride = if stage > 0 && b == 0 { 2 } else { 1 };
                blocks.push(BasicBlock::new(cin, cout, stride, device));
                cin = cout;
            }
        }
        let embed = self
            .embed_dim
            .map(|e| LinearConfig::new(self.feature_dim(), e).init(device));
        let gap = AdaptiveAvgPool2dConfig::new([1, 1]).init();
        Encoder {
            stem,
            stem_bn,
            pool,
            blocks,
            gap,
            embed,
        }
    }
}

fn conv3x3(cin: usize, cout: usize, stride: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([cin, cout], [3, 3])
        .with_stride([stride, stride])
        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
        .with_bias(false)
        .init(device)
}

/// 1x1 convolution + batch norm on the shortcut when the shape changes.
#[derive(Module, Debug)]
pub struct Downsample {
    conv: Conv2d,
    bn: BatchNorm,
}

/// ResNet basic block (two 3x3 convolutions and a shortcut).
#[derive(Module, Debug)]
pub struct BasicBlock {
    conv1: Conv2d,
    bn1: BatchNorm,
    conv2: Conv2d,
    bn2: BatchNorm,
    down: Option<Downsample>,
}

impl BasicBlock {
    fn new(cin: usize, cout: usize, stride: usize, device: &Device) -> Self {
        let down = (stride != 1 || cin != cout).then(|| Downsample {
            conv: Conv2dConfig::new([cin, cout], [1, 1])
                .with_stride([stride, stride])
                .with_bias(false)
                .init(device),
            bn: BatchNormConfig::new(cout).init(device),
        });
        BasicBlock {
            conv1: conv3x3(cin, cout, stride, device),
            bn1: BatchNormConfig::new(cout).init(device),
            conv2: conv3x3(cout, cout, 1, device),
            bn2: BatchNormConfig::new(cout).init(device),
            down,
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let identity = match &self.down {
            Some(d) => d.bn.forward(d.conv.forward(x.clone())),
            None => x.clone(),
        };
        let y = relu(self.bn1.forward(self.conv1.forward(x)));
        let y = self.bn2.forward(self.conv2.forward(y));
        relu(y + identity)
    }
}

/// The exported encoder: frames `[N, 3, S, S]` -> embedding `[N, D]`.
#[derive(Module, Debug)]
pub struct Encoder {
    stem: Conv2d,
    stem_bn: BatchNorm,
    pool: MaxPool2d,
    blocks: Vec<BasicBlock>,
    gap: AdaptiveAvgPool2d,
    embed: Option<Linear>,
}

impl Encoder {
    /// Forward pass (not normalised; consumers L2-normalise).
    pub fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        let x = relu(self.stem_bn.forward(self.stem.forward(x)));
        let mut x = self.pool.forward(x);
        for b in &self.blocks {
            x = b.forward(x);
        }
        // Global average pooling (ONNX GlobalAveragePool), then [N, C].
        let x: Tensor<2> = self.gap.forward(x).flatten(1, 3);
        match &self.embed {
            Some(l) => l.forward(x),
            None => x,
        }
    }
}

/// Query (or key) network used during MoCo training: encoder + MLP head.
#[derive(Module, Debug)]
pub struct MocoNet {
    /// The backbone that is exported.
    pub encoder: Encoder,
    head1: Linear,
    head2: Linear,
}

impl MocoNet {
    /// Encoder plus a 2-layer MLP projection head to `proj_dim`.
    pub fn new(arch: &ArchConfig, proj_dim: usize, device: &Device) -> Self {
        let d = arch.embedding_dim();
        MocoNet {
            encoder: arch.init_encoder(device),
            head1: LinearConfig::new(d, d).init(device),
            head2: LinearConfig::new(d, proj_dim).init(device),
        }
    }

    /// Projection used by the contrastive loss.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        let h = self.encoder.forward(x);
        self.head2.forward(relu(self.head1.forward(h)))
    }
}

/// Row-wise L2 normalisation.
pub fn l2_normalize(x: Tensor<2>) -> Tensor<2> {
    let norm = x
        .clone()
        .powf_scalar(2.0)
        .sum_dim(1)
        .sqrt()
        .clamp_min(1e-12);
    x / norm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arch_names_round_trip() {
        for a in [
            ArchConfig::resnet18(),
            ArchConfig {
                blocks: [1, 1, 1, 1],
                width: 16,
                input: 64,
                embed_dim: None,
            },
            ArchConfig {
                blocks: [1, 2, 1, 1],
                width: 8,
                input: 96,
                embed_dim: Some(64),
            },
        ] {
            assert_eq!(ArchConfig::parse(&a.name()).unwrap(), a);
        }
        assert_eq!(ArchConfig::resnet18().name(), "resnet18-w64-s224");
        for bad in [
            "",
            "vgg-w1-s64",
            "resnet-d11-w8-s64",
            "resnet-d1111-s64",
            "resnet-d1111-w8-s64-x3",
        ] {
            assert!(ArchConfig::parse(bad).is_err(), "{bad}");
        }
    }
}
