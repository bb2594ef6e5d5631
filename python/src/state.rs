//! A small binary encoding for pickling the extension's classes (`DescribedScan`, `PairResult`): little-endian
//! numbers and length-prefixed arrays behind a magic tag, so values come back bit for bit (no decimal round trip)
//! and a truncated or foreign state is refused with a `ValueError` naming the class.

use crate::errors::value_error;
use pyo3::PyResult;

/// Appends values to a state buffer.
pub(crate) struct Writer {
    /// The encoded bytes so far.
    pub bytes: Vec<u8>,
}

impl Writer {
    /// A buffer that starts with `magic`.
    pub fn new(magic: &[u8]) -> Writer {
        Writer { bytes: magic.to_vec() }
    }

    /// One unsigned integer.
    pub fn u64(&mut self, v: u64) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }

    /// One signed integer.
    pub fn i64(&mut self, v: i64) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }

    /// One float, bit for bit.
    pub fn f64(&mut self, v: f64) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }

    /// A length, then the floats.
    pub fn f32s(&mut self, values: &[f32]) {
        self.u64(values.len() as u64);
        for v in values {
            self.bytes.extend_from_slice(&v.to_le_bytes());
        }
    }

    /// A length, then the integers.
    pub fn u32s(&mut self, values: &[u32]) {
        self.u64(values.len() as u64);
        for v in values {
            self.bytes.extend_from_slice(&v.to_le_bytes());
        }
    }

    /// A length, then the floats.
    pub fn f64s(&mut self, values: &[f64]) {
        self.u64(values.len() as u64);
        for &v in values {
            self.f64(v);
        }
    }

    /// A length, then the UTF-8 bytes.
    pub fn str(&mut self, s: &str) {
        self.u64(s.len() as u64);
        self.bytes.extend_from_slice(s.as_bytes());
    }

    /// A presence flag, then the string.
    pub fn opt_str(&mut self, s: Option<&str>) {
        self.u64(u64::from(s.is_some()));
        if let Some(s) = s {
            self.str(s);
        }
    }
}

/// Reads values back in the order they were written.
pub(crate) struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    what: &'static str,
}

impl<'a> Reader<'a> {
    /// A reader of `bytes`, which must start with `magic`; `what` names the class in errors.
    pub fn new(bytes: &'a [u8], magic: &[u8], what: &'static str) -> PyResult<Reader<'a>> {
        if !bytes.starts_with(magic) {
            return Err(value_error(format!("{what}: not a pickled {what} of this dpr_gpu version")));
        }
        Ok(Reader { bytes, at: magic.len(), what })
    }

    fn take(&mut self, n: usize) -> PyResult<&'a [u8]> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| value_error(format!("{}: the pickled state is truncated", self.what)))?;
        let out = &self.bytes[self.at..end];
        self.at = end;
        Ok(out)
    }

    fn word(&mut self) -> PyResult<[u8; 8]> {
        Ok(self.take(8)?.try_into().expect("8 bytes"))
    }

    /// One unsigned integer.
    pub fn u64(&mut self) -> PyResult<u64> {
        Ok(u64::from_le_bytes(self.word()?))
    }

    /// One unsigned integer as a count or index.
    pub fn usize(&mut self) -> PyResult<usize> {
        let v = self.u64()?;
        usize::try_from(v).map_err(|_| value_error(format!("{}: count {v} is out of range", self.what)))
    }

    /// One signed integer.
    pub fn i64(&mut self) -> PyResult<i64> {
        Ok(i64::from_le_bytes(self.word()?))
    }

    /// One float.
    pub fn f64(&mut self) -> PyResult<f64> {
        Ok(f64::from_le_bytes(self.word()?))
    }

    /// A length-prefixed float array.
    pub fn f32s(&mut self) -> PyResult<Vec<f32>> {
        let n = self.usize()?;
        let raw = self.take(n.checked_mul(4).ok_or_else(|| value_error(format!("{}: bad length", self.what)))?)?;
        Ok(raw.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes"))).collect())
    }

    /// A length-prefixed integer array.
    pub fn u32s(&mut self) -> PyResult<Vec<u32>> {
        let n = self.usize()?;
        let raw = self.take(n.checked_mul(4).ok_or_else(|| value_error(format!("{}: bad length", self.what)))?)?;
        Ok(raw.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes"))).collect())
    }

    /// A length-prefixed float array.
    pub fn f64s(&mut self) -> PyResult<Vec<f64>> {
        let n = self.usize()?;
        let raw = self.take(n.checked_mul(8).ok_or_else(|| value_error(format!("{}: bad length", self.what)))?)?;
        Ok(raw.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes"))).collect())
    }

    /// A length-prefixed UTF-8 string.
    pub fn str(&mut self) -> PyResult<String> {
        let n = self.usize()?;
        let raw = self.take(n)?;
        String::from_utf8(raw.to_vec()).map_err(|_| value_error(format!("{}: a string is not UTF-8", self.what)))
    }

    /// An optional string.
    pub fn opt_str(&mut self) -> PyResult<Option<String>> {
        Ok(if self.u64()? != 0 { Some(self.str()?) } else { None })
    }

    /// Fails unless every byte was read.
    pub fn finish(self) -> PyResult<()> {
        if self.at == self.bytes.len() {
            Ok(())
        } else {
            Err(value_error(format!(
                "{}: {} unexpected bytes after the pickled state",
                self.what,
                self.bytes.len() - self.at
            )))
        }
    }
}

/// `values` (a multiple of 3 long) as points; `what` names the array in errors.
pub(crate) fn triples(values: Vec<f32>, what: &'static str) -> PyResult<Vec<[f32; 3]>> {
    if !values.len().is_multiple_of(3) {
        return Err(value_error(format!("{what}: a point array's length is not a multiple of 3")));
    }
    Ok(values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// Points flattened to floats.
pub(crate) fn flat(points: &[[f32; 3]]) -> Vec<f32> {
    points.iter().flatten().copied().collect()
}
