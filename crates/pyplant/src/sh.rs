//! Binding of the spherical-harmonics colour evaluation (the rasterizer's SH colours).

use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods};
use pyo3::prelude::*;
use splat_core::raster::sh;

use crate::arrays::{expect_shape, f32_array};
use crate::errors::InputError;
use crate::ints::usize_from;

/// SH colour before the +0.5 offset: coeffs [N, K, 3], dirs [N, 3] (any length) -> [N, 3].
#[pyfunction]
fn eval_sh<'py>(
    py: Python<'py>,
    degree: &Bound<'py, PyAny>,
    coeffs: &Bound<'py, PyAny>,
    dirs: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let degree = usize_from(degree, "degree", 0)?;
    let (cs, c) = f32_array("coeffs", coeffs, 3)?;
    let n = cs[0];
    expect_shape("coeffs", &cs, &[Some(n), None, Some(3)])?;
    let (ds, d) = f32_array("dirs", dirs, 2)?;
    expect_shape("dirs", &ds, &[Some(n), Some(3)])?;
    if degree > 3 || cs[1] < sh::num_bases(degree) {
        return Err(InputError::new_err(format!(
            "degree {degree} needs 0..=3 and (degree+1)^2 <= K = {}",
            cs[1]
        )));
    }
    let k = cs[1];
    let out: Vec<f32> = (0..n)
        .flat_map(|i| {
            let dir = sh::Vec3::new(d[3 * i], d[3 * i + 1], d[3 * i + 2]);
            sh::eval(degree, &c[i * k * 3..(i + 1) * k * 3], dir)
        })
        .collect();
    out.into_pyarray(py).reshape(vec![n, 3])
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(eval_sh, m)?)?;
    Ok(())
}
