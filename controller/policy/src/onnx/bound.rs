//! Inference without allocation: the input and output tensors are created once over buffers this
//! struct owns, and each run is one call of ONNX Runtime's C `Run` with those tensors bound.
//! (`ort`'s safe `Session::run` builds its input list and output map on every call.)

#![allow(
    unsafe_code,
    reason = "ONNX Runtime's C API, with pointers this module owns and releases"
)]

use std::ffi::{CStr, CString, c_char, c_void};

use ort::AsPointer;
use ort::session::Session;
use ort::sys::{
    ONNXTensorElementDataType, OrtAllocatorType, OrtMemType, OrtMemoryInfo, OrtStatusPtr, OrtValue,
};

/// One bound tensor: its name, the buffer it lives in, its ONNX Runtime value.
#[derive(Debug)]
struct Bound {
    _name: CString,
    buffer: Box<[f32]>,
    value: *mut OrtValue,
}

/// Input and output tensors bound to owned buffers.
#[derive(Debug)]
pub(super) struct BoundTensors {
    memory: *mut OrtMemoryInfo,
    inputs: Vec<Bound>,
    /// The action output first, then the others in the model's order.
    outputs: Vec<Bound>,
    input_names: Vec<*const c_char>,
    input_values: Vec<*const OrtValue>,
    output_names: Vec<*const c_char>,
    output_values: Vec<*mut OrtValue>,
}

// SAFETY: the tensors and memory info are plain heap objects of ONNX Runtime owned by this struct
// alone; moving them to another thread is sound (ONNX Runtime has no thread affinity for them).
unsafe impl Send for BoundTensors {}

/// A call into ONNX Runtime's C API that returned an error status.
#[derive(Debug, thiserror::Error)]
#[error("{call}: {message}")]
pub(super) struct OrtCallFailed {
    /// The C function.
    call: &'static str,
    /// ONNX Runtime's message.
    message: String,
}

fn check(call: &'static str, status: OrtStatusPtr) -> Result<(), OrtCallFailed> {
    if status.0.is_null() {
        return Ok(());
    }
    let api = ort::api();
    // SAFETY: a non-null status from the API; its message lives until the status is released.
    let message = unsafe { CStr::from_ptr((api.GetErrorMessage)(status.0)) }
        .to_string_lossy()
        .into_owned();
    // SAFETY: released once, after reading its message.
    unsafe { (api.ReleaseStatus)(status.0) };
    Err(OrtCallFailed { call, message })
}

/// A float tensor of `shape` over a new buffer.
fn tensor(memory: *mut OrtMemoryInfo, name: &str, shape: &[i64]) -> Result<Bound, OrtCallFailed> {
    let n = shape.iter().product::<i64>().max(0) as usize;
    let mut bound = Bound {
        _name: CString::new(name).map_err(|e| OrtCallFailed {
            call: "CreateTensorWithDataAsOrtValue",
            message: format!("tensor name {name:?}: {e}"),
        })?,
        buffer: vec![0.0; n].into_boxed_slice(),
        value: std::ptr::null_mut(),
    };
    // SAFETY: the buffer is owned by `bound` and outlives the value (released first in Drop).
    unsafe {
        check(
            "CreateTensorWithDataAsOrtValue",
            (ort::api().CreateTensorWithDataAsOrtValue)(
                memory,
                bound.buffer.as_mut_ptr().cast::<c_void>(),
                n * size_of::<f32>(),
                shape.as_ptr(),
                shape.len(),
                ONNXTensorElementDataType::ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT,
                &mut bound.value,
            ),
        )?;
    }
    Ok(bound)
}

impl BoundTensors {
    /// A tensor of its shape for each input (in the session's order) and for each output (the
    /// action output first).
    pub(super) fn new(
        inputs: &[(String, Vec<i64>)],
        outputs: &[(String, Vec<i64>)],
    ) -> Result<Self, OrtCallFailed> {
        let mut memory = std::ptr::null_mut();
        // SAFETY: out-pointer to a local; released in Drop (or below on error).
        check("CreateCpuMemoryInfo", unsafe {
            (ort::api().CreateCpuMemoryInfo)(
                OrtAllocatorType::OrtArenaAllocator,
                OrtMemType::OrtMemTypeDefault,
                &mut memory,
            )
        })?;
        let mut this = Self {
            memory,
            inputs: Vec::with_capacity(inputs.len()),
            outputs: Vec::with_capacity(outputs.len()),
            input_names: Vec::with_capacity(inputs.len()),
            input_values: Vec::with_capacity(inputs.len()),
            output_names: Vec::with_capacity(outputs.len()),
            output_values: Vec::with_capacity(outputs.len()),
        };
        for (name, shape) in inputs {
            let b = tensor(memory, name, shape)?;
            this.input_names.push(b._name.as_ptr());
            this.input_values.push(b.value.cast_const());
            this.inputs.push(b);
        }
        for (name, shape) in outputs {
            let b = tensor(memory, name, shape)?;
            this.output_names.push(b._name.as_ptr());
            this.output_values.push(b.value);
            this.outputs.push(b);
        }
        Ok(this)
    }

    /// The values output `k` (in the order given to [`Self::new`]) held after the last run.
    pub(super) fn output(&self, k: usize) -> &[f32] {
        &self.outputs[k].buffer
    }

    /// Copies `obs` into the inputs (consecutive blocks, in input order), runs `session`, copies
    /// the actions out (the other outputs stay in their buffers, see [`Self::output`]). Buffer sizes are checked by the caller.
    pub(super) fn run(
        &mut self,
        session: &mut Session,
        obs: &[f32],
        actions: &mut [f32],
    ) -> Result<(), OrtCallFailed> {
        let mut at = 0;
        for input in &mut self.inputs {
            let n = input.buffer.len();
            input.buffer.copy_from_slice(&obs[at..at + n]);
            at += n;
        }
        // SAFETY: the session is live (borrowed mutably for the call); names and tensors are owned
        // by `self` and outlive the call; the output tensor is pre-allocated with the model's shape,
        // so ONNX Runtime writes into our buffer instead of allocating.
        unsafe {
            check(
                "Run",
                (ort::api().Run)(
                    session.ptr_mut(),
                    std::ptr::null(),
                    self.input_names.as_ptr(),
                    self.input_values.as_ptr(),
                    self.inputs.len(),
                    self.output_names.as_ptr(),
                    self.outputs.len(),
                    self.output_values.as_mut_ptr(),
                ),
            )?;
        }
        actions.copy_from_slice(&self.outputs[0].buffer);
        Ok(())
    }
}

impl Drop for BoundTensors {
    fn drop(&mut self) {
        let api = ort::api();
        // SAFETY: each pointer was created by the API, is released once, and null ones are skipped.
        unsafe {
            for b in self.inputs.iter().chain(&self.outputs) {
                if !b.value.is_null() {
                    (api.ReleaseValue)(b.value);
                }
            }
            if !self.memory.is_null() {
                (api.ReleaseMemoryInfo)(self.memory);
            }
        }
    }
}
