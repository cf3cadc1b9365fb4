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
    output: Bound,
    input_names: Vec<*const c_char>,
    input_values: Vec<*const OrtValue>,
    output_name: *const c_char,
}

// SAFETY: the tensors and memory info are plain heap objects of ONNX Runtime owned by this struct
// alone; moving them to another thread is sound (ONNX Runtime has no thread affinity for them).
unsafe impl Send for BoundTensors {}

fn check(status: OrtStatusPtr) -> Result<(), String> {
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
    Err(message)
}

/// A `[1, n]` float tensor over a new buffer.
fn tensor(memory: *mut OrtMemoryInfo, name: &str, n: usize) -> Result<Bound, String> {
    let mut bound = Bound {
        _name: CString::new(name).map_err(|e| e.to_string())?,
        buffer: vec![0.0; n].into_boxed_slice(),
        value: std::ptr::null_mut(),
    };
    let shape = [1i64, n as i64];
    // SAFETY: the buffer is owned by `bound` and outlives the value (released first in Drop).
    unsafe {
        check((ort::api().CreateTensorWithDataAsOrtValue)(
            memory,
            bound.buffer.as_mut_ptr().cast::<c_void>(),
            n * size_of::<f32>(),
            shape.as_ptr(),
            2,
            ONNXTensorElementDataType::ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT,
            &mut bound.value,
        ))?;
    }
    Ok(bound)
}

impl BoundTensors {
    /// Tensors `[1, n]` for each input (in the session's order) and the output.
    pub(super) fn new(inputs: &[(String, usize)], output_name: &str, n_out: usize) -> Result<Self, String> {
        let mut memory = std::ptr::null_mut();
        // SAFETY: out-pointer to a local; released in Drop (or below on error).
        check(unsafe {
            (ort::api().CreateCpuMemoryInfo)(
                OrtAllocatorType::OrtArenaAllocator,
                OrtMemType::OrtMemTypeDefault,
                &mut memory,
            )
        })?;
        let mut this = Self {
            memory,
            inputs: Vec::with_capacity(inputs.len()),
            output: Bound {
                _name: CString::default(),
                buffer: Box::new([]),
                value: std::ptr::null_mut(),
            },
            input_names: Vec::with_capacity(inputs.len()),
            input_values: Vec::with_capacity(inputs.len()),
            output_name: std::ptr::null(),
        };
        for (name, n) in inputs {
            let b = tensor(memory, name, *n)?;
            this.input_names.push(b._name.as_ptr());
            this.input_values.push(b.value.cast_const());
            this.inputs.push(b);
        }
        this.output = tensor(memory, output_name, n_out)?;
        this.output_name = this.output._name.as_ptr();
        Ok(this)
    }

    /// Copies `obs` into the inputs (consecutive blocks, in input order), runs `session`, copies
    /// the actions out. Buffer sizes are checked by the caller.
    pub(super) fn run(
        &mut self,
        session: &mut Session,
        obs: &[f32],
        actions: &mut [f32],
    ) -> Result<(), String> {
        let mut at = 0;
        for input in &mut self.inputs {
            let n = input.buffer.len();
            input.buffer.copy_from_slice(&obs[at..at + n]);
            at += n;
        }
        let mut outputs = [self.output.value];
        // SAFETY: the session is live (borrowed mutably for the call); names and tensors are owned
        // by `self` and outlive the call; the output tensor is pre-allocated with the model's shape,
        // so ONNX Runtime writes into our buffer instead of allocating.
        unsafe {
            check((ort::api().Run)(
                session.ptr_mut(),
                std::ptr::null(),
                self.input_names.as_ptr(),
                self.input_values.as_ptr(),
                self.inputs.len(),
                &self.output_name,
                1,
                outputs.as_mut_ptr(),
            ))?;
        }
        actions.copy_from_slice(&self.output.buffer);
        Ok(())
    }
}

impl Drop for BoundTensors {
    fn drop(&mut self) {
        let api = ort::api();
        // SAFETY: each pointer was created by the API, is released once, and null ones are skipped.
        unsafe {
            for b in self.inputs.iter().chain(std::iter::once(&self.output)) {
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
