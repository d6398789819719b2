//! Numbers across the boundary without the numpy crate: its ndarray would turn on
//! matrixmultiply's `cgemm` for the whole workspace, so that nalgebra and every crate
//! above it would be compiled twice (once for the tests and the fuzz targets, once for
//! the package). Values go out as `(dtype, shape, bytearray)`, native-endian, which the
//! Python half views with `np.frombuffer` (no copy, writable); columns come in as the
//! bytes of a float64 array.

use pyo3::prelude::*;
use pyo3::types::{PyByteArray, PyBytes};

/// A number type numpy knows, written native-endian.
pub trait Native: Copy {
    /// Its numpy dtype.
    const DTYPE: &'static str;
    const SIZE: usize;
    fn write(self, out: &mut [u8]);
}

macro_rules! native {
    ($t:ty, $dtype:literal) => {
        impl Native for $t {
            const DTYPE: &'static str = $dtype;
            const SIZE: usize = std::mem::size_of::<$t>();
            fn write(self, out: &mut [u8]) {
                out.copy_from_slice(&self.to_ne_bytes());
            }
        }
    };
}

// No uint64: a difference of two would wrap (to 1.8e19) where it should be negative;
// times, indices and counters go out as int64 (src/logs.rs).
native!(f64, "=f8");
native!(i64, "=i8");
native!(u32, "=u4");

impl Native for bool {
    const DTYPE: &'static str = "?";
    const SIZE: usize = 1;
    fn write(self, out: &mut [u8]) {
        out[0] = u8::from(self);
    }
}

/// `values` as `(dtype, shape, bytearray)` for the Python half's `_arrays.array`.
pub fn out<'py, T: Native>(
    py: Python<'py>,
    values: &[T],
    shape: Vec<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    let buf = PyByteArray::new_with(py, values.len() * T::SIZE, |buf: &mut [u8]| {
        for (chunk, v) in buf.chunks_exact_mut(T::SIZE).zip(values) {
            v.write(chunk);
        }
        Ok(())
    })?;
    Ok((T::DTYPE, shape, buf).into_pyobject(py)?.into_any())
}

/// The float64 values of an array's bytes (`np.ascontiguousarray(a, float64).tobytes()`).
pub fn f64s(bytes: &Bound<'_, PyBytes>) -> anyhow::Result<Vec<f64>> {
    let b = bytes.as_bytes();
    anyhow::ensure!(
        b.len() % 8 == 0,
        "{} bytes are not a whole number of float64 values",
        b.len()
    );
    Ok(b.chunks_exact(8)
        .map(|c| f64::from_ne_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
        .collect())
}
