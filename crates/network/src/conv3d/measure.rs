//! A layer's products on a kernel named by the caller, for `nst3d bench
//! conv3d`: the measurements [`super::route`]'s rule was read from, to be
//! taken again on another CPU.

use nst3d_core::precision::{self, Product};

use super::direct::{self, Arith};
use super::route::{self, Route};
use super::{kernels, tiles, Conv3d};
use crate::activation::Act;
use crate::volume::Volume;

/// A kernel a layer's products can run on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel3d {
    /// AMX tiles.
    Tiles,
    /// The direct kernels in bf16 (AVX512-BF16).
    Bf16Direct,
    /// The direct kernels in fp32 (AVX-512).
    Fp32Direct,
}

impl Kernel3d {
    /// Every kernel, in the order tables show them.
    pub const ALL: [Kernel3d; 3] = [Kernel3d::Tiles, Kernel3d::Bf16Direct, Kernel3d::Fp32Direct];

    /// The name tables show.
    pub fn name(self) -> &'static str {
        match self {
            Kernel3d::Tiles => "tiles",
            Kernel3d::Bf16Direct => "bf16 direct",
            Kernel3d::Fp32Direct => "fp32 direct",
        }
    }

    fn route(self) -> Route {
        match self {
            Kernel3d::Tiles => Route::Tiles,
            Kernel3d::Bf16Direct => Route::Direct(Arith::Bf16),
            Kernel3d::Fp32Direct => Route::Direct(Arith::F32),
        }
    }

    fn of(route: Route) -> Option<Kernel3d> {
        Kernel3d::ALL.into_iter().find(|k| k.route() == route)
    }
}

/// Which of a layer's products a measurement is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Conv3dProduct {
    /// The forward.
    Forward,
    /// The weight gradient.
    WeightGrad,
    /// The input gradient of a stride-1 layer (its transposed layer's forward).
    InputGrad,
}

impl Conv3d {
    /// Runs `product` of this layer on `kernel` (input `x`, output gradient
    /// `grad_out`); `false` where this machine lacks the kernel or the
    /// kernel cannot take the product (the input gradient of a strided
    /// layer is a scatter, on no kernel of these).
    pub fn run_on(&self, kernel: Kernel3d, product: Conv3dProduct, x: &Volume, grad_out: &Volume) -> bool {
        let unit = kernels::unit();
        let layer = match product {
            Conv3dProduct::InputGrad if self.stride != 1 => return false,
            Conv3dProduct::InputGrad => self.transposed(),
            _ => self.clone(),
        };
        let here = match kernel {
            Kernel3d::Tiles if product == Conv3dProduct::WeightGrad => tiles::takes_weight_grad(&layer),
            Kernel3d::Tiles => tiles::takes_forward(&layer),
            Kernel3d::Bf16Direct => unit.bf16,
            Kernel3d::Fp32Direct => unit.has_f32(),
        };
        if !here {
            return false;
        }
        match (kernel.route(), product) {
            (Route::Tiles, Conv3dProduct::WeightGrad) => drop(tiles::weight_grad(&layer, x, grad_out)),
            (Route::Tiles, Conv3dProduct::Forward) => drop(tiles::forward(&layer, x, Act::Identity)),
            (Route::Tiles, Conv3dProduct::InputGrad) => drop(tiles::forward(&layer, grad_out, Act::Identity)),
            (Route::Direct(a), Conv3dProduct::WeightGrad) => drop(direct::weight_grad(&layer, a, x, grad_out)),
            (Route::Direct(a), Conv3dProduct::Forward) => drop(direct::forward(&layer, a, x, Act::Identity)),
            (Route::Direct(a), Conv3dProduct::InputGrad) => drop(direct::forward(&layer, a, grad_out, Act::Identity)),
            (Route::Im2col, _) => unreachable!("no named kernel is im2col"),
        }
        true
    }

    /// The kernel the precision in force runs `product` of this layer on
    /// (`None`: im2col products, or the strided input gradient's scatter).
    pub fn chosen_kernel(&self, product: Conv3dProduct) -> Option<Kernel3d> {
        let path = precision::path_for(Product::Conv3d);
        let direct = super::direct_arith(path);
        let r = match product {
            Conv3dProduct::Forward => route::forward(self, path, direct),
            Conv3dProduct::WeightGrad => route::weight_grad(self, path, direct),
            Conv3dProduct::InputGrad if self.stride == 1 => route::forward(&self.transposed(), path, direct),
            Conv3dProduct::InputGrad => return None,
        };
        Kernel3d::of(r)
    }
}
