//! Tests of the crate's internals: the GPU contract (every shader against the Rust tables, by
//! naga) and each GPU pass against analytic answers and the CPU twin. Tests of the public API
//! alone are in `runtime/tests/`.

mod contract;
pub(crate) mod passes;
