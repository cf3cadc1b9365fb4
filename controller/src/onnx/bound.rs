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

/// Input and output tensors bound to owned buffers.
#[derive(Debug)]
pub(super) struct BoundTensors {
    obs: Box<[f32]>,
    actions: Box<[f32]>,
    memory: *mut OrtMemoryInfo,
    input: *mut OrtValue,
    output: *mut OrtValue,
    _names: [CString; 2],
    input_name: *const c_char,
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

impl BoundTensors {
    /// Tensors `[1, n_in]` and `[1, n_out]` for a session whose input/output carry these names.
    pub(super) fn new(
        input_name: &str,
        n_in: usize,
        output_name: &str,
        n_out: usize,
    ) -> Result<Self, String> {
        let api = ort::api();
        let names = [
            CString::new(input_name).map_err(|e| e.to_string())?,
            CString::new(output_name).map_err(|e| e.to_string())?,
        ];
        let mut bound = Self {
            obs: vec![0.0; n_in].into_boxed_slice(),
            actions: vec![0.0; n_out].into_boxed_slice(),
            memory: std::ptr::null_mut(),
            input: std::ptr::null_mut(),
            output: std::ptr::null_mut(),
            input_name: names[0].as_ptr(),
            output_name: names[1].as_ptr(),
            _names: names,
        };
        // SAFETY: out-pointers to fields of `bound`; on error the partially built struct is dropped,
        // and Drop releases exactly the non-null pointers.
        unsafe {
            check((api.CreateCpuMemoryInfo)(
                OrtAllocatorType::OrtArenaAllocator,
                OrtMemType::OrtMemTypeDefault,
                &mut bound.memory,
            ))?;
            let shape_in = [1i64, n_in as i64];
            check((api.CreateTensorWithDataAsOrtValue)(
                bound.memory,
                bound.obs.as_mut_ptr().cast::<c_void>(),
                n_in * size_of::<f32>(),
                shape_in.as_ptr(),
                2,
                ONNXTensorElementDataType::ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT,
                &mut bound.input,
            ))?;
            let shape_out = [1i64, n_out as i64];
            check((api.CreateTensorWithDataAsOrtValue)(
                bound.memory,
                bound.actions.as_mut_ptr().cast::<c_void>(),
                n_out * size_of::<f32>(),
                shape_out.as_ptr(),
                2,
                ONNXTensorElementDataType::ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT,
                &mut bound.output,
            ))?;
        }
        Ok(bound)
    }

    /// Copies `obs` in, runs `session`, copies the actions out. Buffer sizes are checked by the caller.
    pub(super) fn run(
        &mut self,
        session: &mut Session,
        obs: &[f32],
        actions: &mut [f32],
    ) -> Result<(), String> {
        self.obs.copy_from_slice(obs);
        let api = ort::api();
        let inputs = [self.input.cast_const()];
        let mut outputs = [self.output];
        // SAFETY: the session is live (borrowed mutably for the call); names and tensors are owned
        // by `self` and outlive the call; the output tensor is pre-allocated with the model's shape,
        // so ONNX Runtime writes into `self.actions` instead of allocating.
        unsafe {
            check((api.Run)(
                session.ptr_mut(),
                std::ptr::null(),
                &self.input_name,
                inputs.as_ptr(),
                1,
                &self.output_name,
                1,
                outputs.as_mut_ptr(),
            ))?;
        }
        actions.copy_from_slice(&self.actions);
        Ok(())
    }
}

impl Drop for BoundTensors {
    fn drop(&mut self) {
        let api = ort::api();
        // SAFETY: each pointer was created by the API, is released once, and null ones are skipped.
        unsafe {
            if !self.input.is_null() {
                (api.ReleaseValue)(self.input);
            }
            if !self.output.is_null() {
                (api.ReleaseValue)(self.output);
            }
            if !self.memory.is_null() {
                (api.ReleaseMemoryInfo)(self.memory);
            }
        }
    }
}
