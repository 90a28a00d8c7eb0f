//! Reading back the NaN that JSON cannot hold: serde_json writes a NaN
//! f64 as `null` and refuses `null` for an f64, so a result with "no
//! estimate here" entries (NaN) would not read back. These
//! `deserialize_with` helpers take `null` as NaN. Written by hand: serde
//! and serde_json offer no such option, and serde_with's `DefaultOnNull`
//! gives 0, which would pass for an estimate.

use serde::{Deserialize, Deserializer};

fn nan(v: Option<f64>) -> f64 {
    v.unwrap_or(f64::NAN)
}

/// An f64, `null` as NaN.
pub fn f64<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Option::<f64>::deserialize(d).map(nan)
}

/// A list of f64, `null` entries as NaN.
pub fn vec<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
    Vec::<Option<f64>>::deserialize(d).map(|v| v.into_iter().map(nan).collect())
}

/// An optional list of f64 (absent or `null`: `None`), `null` entries as
/// NaN.
pub fn opt_vec<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Vec<f64>>, D::Error> {
    Option::<Vec<Option<f64>>>::deserialize(d).map(|o| o.map(|v| v.into_iter().map(nan).collect()))
}

/// A list of lists of f64, `null` entries as NaN.
pub fn vec2<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<f64>>, D::Error> {
    Vec::<Vec<Option<f64>>>::deserialize(d).map(|v| {
        v.into_iter()
            .map(|r| r.into_iter().map(nan).collect())
            .collect()
    })
}

/// A pair of f64, `null` as NaN.
pub fn pair<'de, D: Deserializer<'de>>(d: D) -> Result<(f64, f64), D::Error> {
    <(Option<f64>, Option<f64>)>::deserialize(d).map(|(a, b)| (nan(a), nan(b)))
}

/// A list of lists of lists of f64, `null` entries as NaN.
pub fn vec3<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<Vec<f64>>>, D::Error> {
    Vec::<Vec<Vec<Option<f64>>>>::deserialize(d).map(|v| {
        v.into_iter()
            .map(|r| {
                r.into_iter()
                    .map(|c| c.into_iter().map(nan).collect())
                    .collect()
            })
            .collect()
    })
}

/// A fixed-size array of f64, `null` entries as NaN.
pub fn arr<'de, D: Deserializer<'de>, const N: usize>(d: D) -> Result<[f64; N], D::Error> {
    let v = Vec::<Option<f64>>::deserialize(d)?;
    let n = v.len();
    <[f64; N]>::try_from(v.into_iter().map(nan).collect::<Vec<_>>())
        .map_err(|_| serde::de::Error::invalid_length(n, &"an array of N numbers"))
}
