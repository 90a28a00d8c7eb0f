//! `.npy` reader. The header is parsed here (a Python dict literal) because
//! ndarray-npy reads neither every integer dtype nor big-endian data.

use std::path::Path;

use ndarray::{Array2, ShapeBuilder};

use super::{ImageFormat, ReadInfo, read_bytes, read_prefix};
use crate::error::{Error, Result};
use crate::field::Field;

const MAGIC: &[u8] = b"\x93NUMPY";

pub(super) fn read(path: &Path) -> Result<(Field, ReadInfo)> {
    let bytes = read_bytes(path)?;
    let bad = |reason: String| Error::format(path, format!("npy: {reason}"));
    let header = Header::parse(&bytes).map_err(bad)?;
    let (ny, nx) = header.image_shape().map_err(bad)?;
    let dtype = Dtype::parse(&header.descr).map_err(bad)?;
    let n = ny
        .checked_mul(nx)
        .and_then(|n| n.checked_mul(dtype.size))
        .ok_or_else(|| bad(format!("shape ({ny}, {nx}) is too large")))?;
    let data = &bytes[header.data_start..];
    if data.len() < n {
        return Err(bad(format!(
            "truncated: shape ({ny}, {nx}) of {} needs {n} data bytes, the file has {}",
            header.descr,
            data.len()
        )));
    }
    let values: Vec<f64> = data[..n]
        .chunks_exact(dtype.size)
        .map(|c| dtype.decode(c))
        .collect();
    let array = if header.fortran_order {
        Array2::from_shape_vec((ny, nx).f(), values).map(|a| a.as_standard_layout().into_owned())
    } else {
        Array2::from_shape_vec((ny, nx), values)
    }
    .map_err(|e| bad(format!("internal shape error: {e}")))?;
    let mut info = ReadInfo::new(ImageFormat::Npy, header.descr.clone());
    if data.len() > n {
        info.warnings.push(format!(
            "{} bytes after the array data ignored",
            data.len() - n
        ));
    }
    Ok((Field::new(array), info))
}

/// The `(ny, nx)` of a `.npy` from its header (super::read_shape): the
/// checks of [`read`] that need no data.
pub(super) fn shape(path: &Path) -> Result<(usize, usize)> {
    let bad = |reason: String| Error::format(path, format!("npy: {reason}"));
    let (prefix, whole) = read_prefix(path)?;
    let header = match Header::parse(&prefix) {
        // a header longer than the prefix (format 2 allows 4 GiB)
        Err(e) if !whole && e == TRUNCATED_HEADER => Header::parse(&read_bytes(path)?),
        h => h,
    }
    .map_err(bad)?;
    Dtype::parse(&header.descr).map_err(bad)?;
    header.image_shape().map_err(bad)
}

/// [`Header::parse`]'s error when the bytes end before the header does.
const TRUNCATED_HEADER: &str = "truncated header";

struct Header {
    descr: String,
    fortran_order: bool,
    shape: Vec<u64>,
    data_start: usize,
}

impl Header {
    fn parse(bytes: &[u8]) -> std::result::Result<Header, String> {
        if bytes.len() < 10 || &bytes[..6] != MAGIC {
            return Err("not a .npy file (bad magic number)".into());
        }
        let major = bytes[6];
        let (len, start): (usize, usize) = match major {
            1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
            2 | 3 => {
                if bytes.len() < 12 {
                    return Err(TRUNCATED_HEADER.into());
                }
                (
                    u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                    12,
                )
            }
            v => return Err(format!("unsupported format version {v}")),
        };
        let end = start
            .checked_add(len)
            .filter(|&e| e <= bytes.len())
            .ok_or(TRUNCATED_HEADER)?;
        let text = std::str::from_utf8(&bytes[start..end]).map_err(|_| "header is not text")?;
        let dict = match PyParser::new(text).value()? {
            Py::Dict(d) => d,
            _ => return Err("header is not a dict".into()),
        };
        let get = |key: &str| {
            dict.iter()
                .find(|(k, _)| k == key)
                .map(|(_, v)| v)
                .ok_or(format!("header has no '{key}'"))
        };
        let descr = match get("descr")? {
            Py::Str(s) => s.clone(),
            Py::List | Py::Tuple(_) => {
                return Err("structured dtypes are not supported (need one numeric dtype)".into());
            }
            _ => return Err("bad 'descr' in header".into()),
        };
        let fortran_order = match get("fortran_order")? {
            Py::Bool(b) => *b,
            _ => return Err("bad 'fortran_order' in header".into()),
        };
        let shape = match get("shape")? {
            Py::Tuple(items) => items
                .iter()
                .map(|v| match v {
                    Py::Int(i) => Ok(*i),
                    _ => Err("bad 'shape' in header".to_string()),
                })
                .collect::<std::result::Result<Vec<_>, _>>()?,
            _ => return Err("bad 'shape' in header".into()),
        };
        Ok(Header {
            descr,
            fortran_order,
            shape,
            data_start: end,
        })
    }

    /// `(ny, nx)` of a 2D array with no empty axis.
    fn image_shape(&self) -> std::result::Result<(usize, usize), String> {
        let Some((ny, nx)) = self.shape2() else {
            return Err(format!(
                "expected a 2D array, got shape {}",
                self.shape_str()
            ));
        };
        if ny == 0 || nx == 0 {
            return Err(format!("empty image (shape ({ny}, {nx}))"));
        }
        Ok((ny, nx))
    }

    fn shape2(&self) -> Option<(usize, usize)> {
        match self.shape[..] {
            [ny, nx] => Some((usize::try_from(ny).ok()?, usize::try_from(nx).ok()?)),
            _ => None,
        }
    }

    fn shape_str(&self) -> String {
        match &self.shape[..] {
            [n] => format!("({n},)"),
            s => format!(
                "({})",
                s.iter()
                    .map(|n| n.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Int,
    Uint,
    Float,
}

#[derive(Debug)]
struct Dtype {
    kind: Kind,
    size: usize,
    big_endian: bool,
}

impl Dtype {
    fn parse(descr: &str) -> std::result::Result<Dtype, String> {
        let mut chars = descr.chars();
        let (order, rest) = match chars.next() {
            Some(c @ ('<' | '>' | '|' | '=')) => (c, chars.as_str()),
            _ => ('=', descr),
        };
        let mut chars = rest.chars();
        let kind_char = chars.next().unwrap_or(' ');
        let size: usize = chars.as_str().parse().unwrap_or(0);
        let kind = match kind_char {
            'i' => Kind::Int,
            'u' => Kind::Uint,
            'f' => Kind::Float,
            'b' | '?' => return Err(format!("bool dtype '{descr}' is not an image dtype")),
            'c' => {
                return Err(format!(
                    "complex dtype '{descr}' is not supported (need real values)"
                ));
            }
            'O' => return Err("object dtype is not supported".into()),
            'S' | 'U' | 'a' => return Err(format!("string dtype '{descr}' is not supported")),
            _ => return Err(format!("unsupported dtype '{descr}'")),
        };
        let ok = match kind {
            Kind::Int | Kind::Uint => matches!(size, 1 | 2 | 4 | 8),
            Kind::Float => matches!(size, 2 | 4 | 8),
        };
        if !ok {
            return Err(format!("unsupported dtype '{descr}'"));
        }
        Ok(Dtype {
            kind,
            size,
            big_endian: order == '>' || (order == '=' && cfg!(target_endian = "big")),
        })
    }

    /// Decodes one element (`c.len() == self.size`).
    fn decode(&self, c: &[u8]) -> f64 {
        let mut b = [0u8; 8];
        b[..self.size].copy_from_slice(c);
        if self.big_endian {
            b[..self.size].reverse();
        }
        // `b` now holds the little-endian bytes, zero-padded.
        let u = u64::from_le_bytes(b);
        match (self.kind, self.size) {
            (Kind::Uint, _) => u as f64,
            (Kind::Int, 1) => u as u8 as i8 as f64,
            (Kind::Int, 2) => u as u16 as i16 as f64,
            (Kind::Int, 4) => u as u32 as i32 as f64,
            (Kind::Int, _) => u as i64 as f64,
            (Kind::Float, 2) => f16_to_f64(u as u16),
            (Kind::Float, 4) => f32::from_bits(u as u32) as f64,
            (Kind::Float, _) => f64::from_bits(u),
        }
    }
}

/// IEEE half precision to f64 (numpy's `f2`).
fn f16_to_f64(h: u16) -> f64 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let frac = (h & 0x3ff) as f64;
    sign * match exp {
        0 => frac * 2f64.powi(-24),
        31 if frac == 0.0 => f64::INFINITY,
        31 => f64::NAN,
        e => (1.0 + frac / 1024.0) * 2f64.powi(e - 15),
    }
}

/// The Python literals that appear in a `.npy` header.
#[derive(Debug)]
enum Py {
    Str(String),
    Int(u64),
    Bool(bool),
    None,
    Tuple(Vec<Py>),
    /// A list (only structured dtypes use one; its items are not needed).
    List,
    Dict(Vec<(String, Py)>),
}

struct PyParser<'a> {
    s: &'a [u8],
    i: usize,
    depth: usize,
}

impl<'a> PyParser<'a> {
    fn new(s: &'a str) -> Self {
        PyParser {
            s: s.as_bytes(),
            i: 0,
            depth: 0,
        }
    }

    fn skip_ws(&mut self) {
        while self.i < self.s.len() && self.s[self.i].is_ascii_whitespace() {
            self.i += 1;
        }
    }

    fn peek(&mut self) -> Option<u8> {
        self.skip_ws();
        self.s.get(self.i).copied()
    }

    fn expect(&mut self, c: u8) -> std::result::Result<(), String> {
        if self.peek() == Some(c) {
            self.i += 1;
            Ok(())
        } else {
            Err(format!("malformed header (expected '{}')", c as char))
        }
    }

    fn value(&mut self) -> std::result::Result<Py, String> {
        // Headers are flat; the limit only stops a hostile file from recursing deeply.
        if self.depth > 16 {
            return Err("malformed header (nested too deeply)".into());
        }
        match self.peek() {
            Some(b'{') => {
                self.i += 1;
                self.depth += 1;
                let mut items = Vec::new();
                while self.peek() != Some(b'}') {
                    let Py::Str(k) = self.value()? else {
                        return Err("malformed header (dict key is not a string)".into());
                    };
                    self.expect(b':')?;
                    items.push((k, self.value()?));
                    if self.peek() == Some(b',') {
                        self.i += 1;
                    } else {
                        break;
                    }
                }
                self.expect(b'}')?;
                self.depth -= 1;
                Ok(Py::Dict(items))
            }
            Some(open @ (b'(' | b'[')) => {
                self.i += 1;
                self.depth += 1;
                let close = if open == b'(' { b')' } else { b']' };
                let mut items = Vec::new();
                while self.peek() != Some(close) {
                    items.push(self.value()?);
                    if self.peek() == Some(b',') {
                        self.i += 1;
                    } else {
                        break;
                    }
                }
                self.expect(close)?;
                self.depth -= 1;
                Ok(if open == b'(' {
                    Py::Tuple(items)
                } else {
                    Py::List
                })
            }
            Some(q @ (b'\'' | b'"')) => {
                self.i += 1;
                let start = self.i;
                while self.i < self.s.len() && self.s[self.i] != q {
                    self.i += 1;
                }
                if self.i >= self.s.len() {
                    return Err("malformed header (unterminated string)".into());
                }
                let text = String::from_utf8_lossy(&self.s[start..self.i]).into_owned();
                self.i += 1;
                Ok(Py::Str(text))
            }
            Some(c) if c.is_ascii_alphanumeric() || c == b'-' => {
                let start = self.i;
                while self.i < self.s.len()
                    && (self.s[self.i].is_ascii_alphanumeric() || self.s[self.i] == b'-')
                {
                    self.i += 1;
                }
                let word = std::str::from_utf8(&self.s[start..self.i]).unwrap_or("");
                match word {
                    "True" => Ok(Py::Bool(true)),
                    "False" => Ok(Py::Bool(false)),
                    "None" => Ok(Py::None),
                    // Python 2 era files may write `3L`.
                    w => w
                        .trim_end_matches('L')
                        .parse()
                        .map(Py::Int)
                        .map_err(|_| format!("malformed header (bad token '{w}')")),
                }
            }
            _ => Err("malformed header".into()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_header_variants() {
        let mut v = b"\x93NUMPY\x01\x00".to_vec();
        let h = "{'descr': '>u2', 'fortran_order': True, 'shape': (3L, 4), }";
        v.extend_from_slice(&(h.len() as u16).to_le_bytes());
        v.extend_from_slice(h.as_bytes());
        let hd = Header::parse(&v).unwrap();
        assert_eq!(hd.descr, ">u2");
        assert!(hd.fortran_order);
        assert_eq!(hd.shape, vec![3, 4]);
    }

    #[test]
    fn decodes_dtypes() {
        let d = Dtype::parse(">i2").unwrap();
        assert_eq!(d.decode(&[0xff, 0xfe]), -2.0);
        let d = Dtype::parse("<f2").unwrap();
        assert_eq!(d.decode(&0x3c00u16.to_le_bytes()), 1.0);
        assert_eq!(d.decode(&0xc000u16.to_le_bytes()), -2.0);
        assert!(Dtype::parse("<c16").unwrap_err().contains("complex"));
        assert!(Dtype::parse("|b1").unwrap_err().contains("bool"));
        assert!(Dtype::parse("<f16").is_err());
    }
}
