#![allow(deprecated)] // burn-ndarray is deprecated upstream; we keep it as an optional cross-check backend.
//! Fused CPU kernels with hand-written backward passes, callable on burn tensors.
//!
//! burn's generic gather/scatter and per-sample elementwise chains are memory-bound on a CPU. A
//! [`HostKernel`] runs one fused loop over host slices instead, and [`host_op`] wires it into
//! burn's autodiff graph through a single backend extension, so every kernel gets
//! differentiation for free once it writes its `backward`.
//!
//! On the forward pass the inputs are read to host memory (free for uniquely owned Flex tensors),
//! the kernel runs, and its single output goes back to the input device. Kernels with several
//! logical outputs pack them into one tensor; callers slice it (slicing is differentiable).

use std::fmt::Debug;
use std::sync::Arc;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, TensorMetadata, backend_extension};
use burn::tensor::{Tensor, TensorData, read_sync};

/// A dense f32 array on the host.
#[derive(Clone, Debug, PartialEq)]
pub struct HostTensor {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

impl HostTensor {
    pub fn new(shape: Vec<usize>, data: Vec<f32>) -> Self {
        debug_assert_eq!(shape.iter().product::<usize>(), data.len(), "shape {shape:?}");
        HostTensor { shape, data }
    }

    pub fn zeros(shape: Vec<usize>) -> Self {
        let n = shape.iter().product();
        HostTensor {
            shape,
            data: vec![0.0; n],
        }
    }
}

/// A CPU kernel with a hand-written backward pass.
pub trait HostKernel: Send + Sync + Debug + 'static {
    /// Computes the single output from the inputs.
    fn forward(&self, inputs: &[HostTensor]) -> HostTensor;

    /// Gradients of the loss with respect to each input, given the gradient with respect to the
    /// output. Entries where `wanted[i]` is false may be `None` (and are ignored).
    fn backward(
        &self,
        inputs: &[HostTensor],
        output: &HostTensor,
        grad_output: &HostTensor,
        wanted: &[bool],
    ) -> Vec<Option<HostTensor>>;
}

/// Shared handle to a kernel, passed through burn's dispatch as an ordinary argument.
#[derive(Clone, Debug)]
pub struct KernelRef(pub Arc<dyn HostKernel>);

#[backend_extension(
    Flex: cfg(feature = "flex"),
    NdArray: cfg(feature = "ndarray"),
    Cube: cfg(any(feature = "wgpu", feature = "cuda")),
    Autodiff
)]
pub trait HostOps: Backend {
    /// Runs `kernel` on the first `arity` of four inputs (all float tensors on one device). The
    /// arity is fixed because the dispatch macro routes bare tensor arguments only; callers pad
    /// with constant one-element tensors, which never require a gradient.
    fn host_op(
        a: FloatTensor<Self>,
        b: FloatTensor<Self>,
        c: FloatTensor<Self>,
        d: FloatTensor<Self>,
        arity: usize,
        kernel: KernelRef,
    ) -> FloatTensor<Self>;
}

fn to_host<B: Backend>(t: FloatTensor<B>) -> HostTensor {
    let shape = t.shape().to_vec();
    // A failure here is a backend fault (device lost), not bad user input.
    let data = read_sync(B::float_into_data(t))
        .map_err(|e| format!("{e:?}"))
        .and_then(|d| d.try_into_vec_as::<f32>().map_err(|e| format!("{e:?}")))
        .unwrap_or_else(|e| panic!("host kernel: cannot read tensor of shape {shape:?}: {e}"));
    HostTensor { shape, data }
}

fn from_host<B: Backend>(t: HostTensor, device: &B::Device) -> FloatTensor<B> {
    B::float_from_data(TensorData::new(t.data, t.shape), device)
}

/// The forward pass on a concrete (non-autodiff) backend.
fn run_plain<B: Backend>(
    inputs: [FloatTensor<B>; ARITY],
    arity: usize,
    kernel: &KernelRef,
) -> FloatTensor<B> {
    let device = inputs[0].device();
    let host: Vec<HostTensor> = inputs.into_iter().take(arity).map(to_host::<B>).collect();
    from_host::<B>(kernel.0.forward(&host), &device)
}

/// A backend that runs the kernels on host slices ([`run_plain`]).
macro_rules! host_ops_on_host {
    ($backend:ty) => {
        impl HostOps for $backend {
            fn host_op(
                a: FloatTensor<Self>,
                b: FloatTensor<Self>,
                c: FloatTensor<Self>,
                d: FloatTensor<Self>,
                arity: usize,
                kernel: KernelRef,
            ) -> FloatTensor<Self> {
                run_plain::<Self>([a, b, c, d], arity, &kernel)
            }
        }
    };
}

#[cfg(feature = "flex")]
host_ops_on_host!(burn::backend::Flex);

#[cfg(feature = "ndarray")]
host_ops_on_host!(burn::backend::NdArray);

// The GPU backends (every cubecl runtime is burn's one `Cube` backend) run the kernels on the
// host too: each call reads its inputs back and uploads its output, so a GPU step pays two
// transfers per fused kernel. Correct everywhere, fast on a CPU; GPU kernels of their own are
// future work (BENCHMARKS.md §9).
#[cfg(any(feature = "wgpu", feature = "cuda"))]
host_ops_on_host!(burn::backend::Cube);

/// What the backward pass keeps: the host copies of inputs and output, the kernel, the device.
#[derive(Clone)]
struct Saved<B: Backend> {
    kernel: KernelRef,
    inputs: Arc<Vec<HostTensor>>,
    output: Arc<HostTensor>,
    device: B::Device,
}

impl<B: Backend> Debug for Saved<B> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Saved({:?})", self.kernel)
    }
}

const ARITY: usize = 4;

#[derive(Debug)]
struct HostBackward;

impl<B: Backend> Backward<B, ARITY> for HostBackward {
    type State = Saved<B>;

    fn backward(self, ops: Ops<Self::State, ARITY>, grads: &mut Gradients, _: &mut Checkpointer) {
        let grad_out = to_host::<B>(grads.consume::<B>(&ops.node));
        let saved = ops.state;
        let arity = saved.inputs.len();
        let wanted: Vec<bool> = ops.parents.iter().take(arity).map(Option::is_some).collect();
        let input_grads = saved
            .kernel
            .0
            .backward(&saved.inputs, &saved.output, &grad_out, &wanted);
        for (parent, grad) in ops.parents.into_iter().take(arity).zip(input_grads) {
            if let (Some(node), Some(g)) = (parent, grad) {
                grads.register::<B>(node.id, from_host::<B>(g, &saved.device));
            }
        }
    }
}

impl<B: HostOps, C: CheckpointStrategy> HostOps for Autodiff<B, C> {
    fn host_op(
        a: FloatTensor<Self>,
        b: FloatTensor<Self>,
        c: FloatTensor<Self>,
        d: FloatTensor<Self>,
        arity: usize,
        kernel: KernelRef,
    ) -> FloatTensor<Self> {
        let inputs = [a, b, c, d];
        let nodes = inputs.each_ref().map(|t| t.node());
        match HostBackward.prepare::<C>(nodes).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let primitives = inputs.map(|t| t.into_primitive());
                let device = primitives[0].device();
                let host: Vec<HostTensor> = primitives.into_iter().take(arity).map(to_host::<B>).collect();
                let output = kernel.0.forward(&host);
                let out = from_host::<B>(output.clone(), &device);
                let saved = Saved::<B> {
                    kernel,
                    inputs: Arc::new(host),
                    output: Arc::new(output),
                    device,
                };
                prep.finish(saved, out)
            }
            OpsKind::UnTracked(prep) => {
                let [a, b, c, d] = inputs.map(|t| t.into_primitive());
                prep.finish(B::host_op(a, b, c, d, arity, kernel))
            }
        }
    }
}

/// Runs `kernel` on rank-2 burn tensors; differentiable when the inputs live on an autodiff
/// device. Callers reshape to and from rank 2 (a free view in burn).
pub fn host_op(inputs: Vec<Tensor<2>>, kernel: Arc<dyn HostKernel>) -> Tensor<2> {
    let arity = inputs.len();
    assert!(
        (1..=ARITY).contains(&arity),
        "host_op takes 1 to {ARITY} inputs, got {arity}"
    );
    let pad = Tensor::<2>::zeros([1, 1], &inputs[0].device());
    let mut it = inputs
        .into_iter()
        .chain(std::iter::repeat(pad))
        .map(|t| t.into_dispatch());
    let mut next = || it.next().unwrap_or_else(|| unreachable!("padded"));
    let (a, b, c, d) = (next(), next(), next(), next());
    Tensor::from_dispatch(Dispatch::host_op(a, b, c, d, arity, KernelRef(kernel)))
}
