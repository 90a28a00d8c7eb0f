//! TIFF reader (one band; of the GeoTIFF tags, GDAL nodata is honoured
//! and the pixel spacing read by [`pixel`]) and float32 writer.

use std::io::{Cursor, Read, Seek, SeekFrom};
use std::path::Path;

use ndarray::Array2;
use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::encoder::{TiffEncoder, colortype};
use tiff::tags::Tag;

use super::{ImageFormat, ReadInfo, check_pixels, field_from, read_bytes};
use crate::error::{Error, Result};
use crate::field::Field;

/// Large enough for a 16k x 16k float32 DEM; a corrupt header asking for more
/// fails cleanly instead of exhausting memory.
const MAX_DECODE_BYTES: usize = 1 << 30;

/// The `(ny, nx)` of a TIFF from its first image directory
/// (super::read_shape): the decoder reads the header and the directory,
/// not the strips.
pub(super) fn shape(path: &Path) -> Result<(usize, usize)> {
    let file = std::fs::File::open(path).map_err(|source| Error::Read {
        path: path.into(),
        source,
    })?;
    let tiff_err = |e: tiff::TiffError| {
        Error::format(
            path,
            format!("TIFF: corrupt or unsupported: {}", decoder_error(&e)),
        )
    };
    let len = file
        .metadata()
        .map(|m| m.len())
        .map_err(|source| Error::Read {
            path: path.into(),
            source,
        })?;
    let mut reader = std::io::BufReader::new(file);
    let corrupt =
        |reason: String| Error::format(path, format!("TIFF: truncated or corrupt: {reason}"));
    let (shape, refusal) = check_layout(&mut reader, len).map_err(corrupt)?;
    if let Some((ny, nx)) = shape {
        check_pixels(path, ny, nx)?;
    }
    if let Some(why) = refusal {
        return Err(Error::format(path, format!("TIFF: {why}")));
    }
    std::io::Seek::rewind(&mut reader).map_err(|source| Error::Read {
        path: path.into(),
        source,
    })?;
    let mut dec = Decoder::new(reader).map_err(tiff_err)?;
    let (w, h) = dec.dimensions().map_err(tiff_err)?;
    let (nx, ny) = (w as usize, h as usize);
    check_pixels(path, ny, nx)?;
    Ok((ny, nx))
}

pub(super) fn read(path: &Path) -> Result<(Field, ReadInfo)> {
    let mut bytes = read_bytes(path)?;
    // The decoder inverts WhiteIsZero samples (255 - v, 1 - v for floats,
    // an error for signed ones) as if they were grey levels; a DEM's values
    // are meant as stored (as GDAL reads them), so the tag is read as
    // BlackIsZero instead.
    let white_is_zero = patch_white_is_zero(&mut bytes);
    let bad = |reason: String| Error::format(path, format!("TIFF: {reason}"));
    let tiff_err =
        |e: tiff::TiffError| bad(format!("corrupt or unsupported: {}", decoder_error(&e)));
    // before the decoder sizes anything by the header
    let corrupt = |reason: String| bad(format!("truncated or corrupt: {reason}"));
    let (shape, refusal) =
        check_layout(&mut Cursor::new(&bytes[..]), bytes.len() as u64).map_err(corrupt)?;
    if let Some((ny, nx)) = shape {
        check_pixels(path, ny, nx)?;
    }
    if let Some(why) = refusal {
        return Err(bad(why));
    }
    let limits = {
        let mut l = Limits::default();
        l.decoding_buffer_size = MAX_DECODE_BYTES;
        l.intermediate_buffer_size = MAX_DECODE_BYTES / 2;
        l
    };
    let mut dec = Decoder::new(Cursor::new(&bytes[..]))
        .map_err(tiff_err)?
        .with_limits(limits);

    let bands: u16 = dec
        .find_tag_unsigned(Tag::SamplesPerPixel)
        .map_err(tiff_err)?
        .unwrap_or(1);
    if bands != 1 {
        return Err(bad(format!(
            "{bands} bands (samples per pixel); only single-band images are supported"
        )));
    }
    // Photometric 3 = palette: the samples are colour indices, not values.
    if dec
        .find_tag_unsigned::<u16>(Tag::PhotometricInterpretation)
        .map_err(tiff_err)?
        == Some(3)
    {
        return Err(bad("palette-colour image; need one band of values".into()));
    }
    let (w, h) = dec.dimensions().map_err(tiff_err)?;
    let (nx, ny) = (w as usize, h as usize);
    if nx == 0 || ny == 0 {
        return Err(bad(format!("empty image ({ny} x {nx})")));
    }
    check_pixels(path, ny, nx)?;
    let bits: u16 = dec
        .find_tag_unsigned(Tag::BitsPerSample)
        .map_err(tiff_err)?
        .unwrap_or(1);
    if !matches!(bits, 8 | 16 | 32 | 64) {
        return Err(bad(format!(
            "unsupported bit depth {bits} (need 8, 16, 32 or 64)"
        )));
    }
    let mut info_warnings = Vec::new();
    // The tag is a number as text. Its byte count is checked before the
    // decoder reads it (it allocates the count first: a corrupt count in
    // a 100-byte file asks for up to the 1 GiB decoding limit), and one
    // that cannot be read is said: dropped in silence, its missing pixels
    // would be read as values.
    let nodata_text = match dec.image_ifd().find_entry(Tag::GdalNodata) {
        None => None,
        Some(entry) if entry.count() > MAX_NODATA_TEXT => {
            info_warnings.push(format!(
                "GDAL nodata tag declares {} bytes, not a number (at most {MAX_NODATA_TEXT}); \
                 ignored: missing pixels, if any, are read as values",
                entry.count()
            ));
            None
        }
        Some(_) => match dec
            .find_tag(Tag::GdalNodata)
            .map(|v| v.map(|v| v.into_string()))
        {
            Ok(Some(Ok(text))) => Some(text),
            Ok(None) => None,
            Ok(Some(Err(e))) | Err(e) => {
                info_warnings.push(format!(
                    "GDAL nodata tag cannot be read ({}); ignored: missing pixels, if any, \
                     are read as values",
                    decoder_error(&e)
                ));
                None
            }
        },
    };
    let more_images = dec.more_images();

    let (dtype, values) = match dec.read_image() {
        Ok(image) => samples(image),
        // the crate's LZW reader fails some valid tiles (tiff_lzw's docs)
        Err(e) if e.to_string().to_lowercase().contains("lzw") => {
            let decoded = super::tiff_lzw::decode(&bytes).map_err(|why| {
                bad(format!(
                    "corrupt or unsupported: {} (and by wtmm's own LZW reader: {why})",
                    decoder_error(&e)
                ))
            })?;
            info_warnings.push(format!(
                "LZW decoded by wtmm's own reader: the tiff crate's stopped with `{}` \
                 (a known fault on valid tiled files, image-rs/image-tiff#395)",
                decoder_error(&e)
            ));
            decoded
        }
        Err(e) => return Err(tiff_err(e)),
    };
    if values.len() < nx * ny {
        return Err(bad(format!(
            "decoded {} samples for a {ny} x {nx} image",
            values.len()
        )));
    }
    let mut values = values;
    values.truncate(nx * ny);

    let mut info = ReadInfo::new(ImageFormat::Tiff, dtype);
    info.warnings = info_warnings;
    let mut nodata = None;
    if let Some(text) = nodata_text {
        let t = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
        match t.parse::<f64>() {
            // A float file stores the nodata rounded to its precision.
            Ok(v) => nodata = Some(super::as_stored(v, dtype)),
            Err(_) => info
                .warnings
                .push(format!("GDAL nodata tag `{t}` is not a number; ignored")),
        }
    }
    if white_is_zero {
        info.warnings.push(
            "photometric interpretation WhiteIsZero: values read as stored, not inverted".into(),
        );
    }
    if more_images {
        info.warnings
            .push("the file holds more than one image; only the first was read".into());
    }
    Ok((field_from(path, ny, nx, values, nodata)?, info))
}

/// The decoder's samples as f64, with their dtype name.
fn samples(image: DecodingResult) -> (&'static str, Vec<f64>) {
    match image {
        DecodingResult::U8(v) => ("u8", v.into_iter().map(f64::from).collect()),
        DecodingResult::U16(v) => ("u16", v.into_iter().map(f64::from).collect()),
        DecodingResult::U32(v) => ("u32", v.into_iter().map(f64::from).collect()),
        DecodingResult::U64(v) => ("u64", v.into_iter().map(|x| x as f64).collect()),
        DecodingResult::I8(v) => ("i8", v.into_iter().map(f64::from).collect()),
        DecodingResult::I16(v) => ("i16", v.into_iter().map(f64::from).collect()),
        DecodingResult::I32(v) => ("i32", v.into_iter().map(f64::from).collect()),
        DecodingResult::I64(v) => ("i64", v.into_iter().map(|x| x as f64).collect()),
        DecodingResult::F16(v) => ("f16", v.into_iter().map(f64::from).collect()),
        DecodingResult::F32(v) => ("f32", v.into_iter().map(f64::from).collect()),
        DecodingResult::F64(v) => ("f64", v),
    }
}

/// The longest GDAL nodata text read: a number (GDAL writes at most ~25
/// characters, e.g. `-3.4028234663852886e+38`), with room for padding.
const MAX_NODATA_TEXT: u64 = 256;

/// A decoder error for a message, cut short: the decoder quotes some
/// corrupt tags whole (a sample format tag of 1000 values is 15 KB of
/// text), which would bury the file's name and the problem.
fn decoder_error(e: &tiff::TiffError) -> String {
    const MAX: usize = 200;
    let s = e.to_string();
    if s.len() <= MAX {
        return s;
    }
    let cut = (0..=MAX)
        .rev()
        .find(|&i| s.is_char_boundary(i))
        .unwrap_or(0);
    format!("{}... ({} more characters)", &s[..cut], s.len() - cut)
}

/// The tags the decoder reads while it opens an image (tiff 0.11,
/// `decoder/image.rs`): the values of each are checked to lie inside the
/// file before it allocates them.
const DECODER_TAGS: [u16; 19] = [
    256, 257, 258, 259, 262, 273, 277, 278, 279, 284, 317, 322, 323, 324, 325, 338, 339, 347, 530,
];

/// The first image directory, checked before the decoder reads it: the
/// decoder sizes a tag's values by its count before it reads them (a
/// corrupt count in a 300-byte file made it allocate up to 255 MiB), and
/// its image buffer by the declared size before it reads a strip. Refused
/// here: a directory or a tag the decoder reads whose values run past the
/// end of the file, an image larger than the file can decompress to, and
/// a compression the decoder does not know. Returns the declared
/// `(ny, nx)` when the directory gives them, and why the image cannot be
/// read (the caller says a size over the pixel limit first); `(None,
/// None)` leaves a file that is not a TIFF, or a header this walk cannot
/// read, to the decoder's own error.
fn check_layout<R: Read + Seek>(r: &mut R, len: u64) -> std::result::Result<Layout, String> {
    let Some(ifd) = Ifd::read(r, len)? else {
        return Ok((None, None));
    };
    let (mut w, mut h, mut bits, mut compression) = (None, None, None, 1u64);
    for e in &ifd.entries {
        let (tag, count) = (e.tag, e.count);
        // unknown types are skipped by the decoder
        let Some(size) = type_size(e.typ) else {
            continue;
        };
        let bytes = count.checked_mul(size);
        if bytes.is_some_and(|b| b <= e.field.len() as u64) {
            // the value sits in the entry; the first one is what we need
            let first = e.field.get(..size as usize).map_or(0, |s| uint(s, ifd.le));
            match (tag, count) {
                (256, 1) => w = Some(first),
                (257, 1) => h = Some(first),
                (258, _) => bits = Some(first),
                (259, 1) => compression = first,
                _ => {}
            }
        } else if DECODER_TAGS.contains(&tag) {
            let at = uint(&e.field, ifd.le);
            if bytes
                .and_then(|b| b.checked_add(at))
                .is_none_or(|e| e > len)
            {
                let name = format!("{:?}", Tag::from_u16_exhaustive(tag));
                return Err(format!(
                    "tag {name} ({tag}) declares {count} values at byte {at}, past the end of the \
                     file ({len} bytes)"
                ));
            }
        }
    }
    let (Some(w), Some(h)) = (w, h) else {
        return Ok((None, None));
    };
    let shape = usize::try_from(h).ok().zip(usize::try_from(w).ok());
    // how far each compression can expand: PackBits a 2-byte run to 128
    // bytes; LZW a code of at least 9 bits to at most 4096 bytes (3641:1);
    // deflate 1032:1 (RFC 1951); none not at all. Others are left to the
    // decoder.
    let ratio = match compression {
        1 => 1,
        32773 => 64,
        5 => 4096,
        8 | 32946 => 1032,
        // what this build's decoder also reads (tiff's default features
        // and zstd), unbounded here: JPEG, CCITT fax 4, zstd
        7 | 4 | 50000 => return Ok((shape, None)),
        // refused now: the decoder would size its buffer by the header
        // before it finds it cannot decode the strips
        c => {
            let why = format!(
                "compression method {c} is not supported (none, LZW, deflate, PackBits, \
                 zstd, JPEG and CCITT fax 4 are)"
            );
            return Ok((shape, Some(why)));
        }
    };
    let need = w
        .checked_mul(h)
        .and_then(|px| px.checked_mul(bits.unwrap_or(1)))
        .map(|b| b.div_ceil(8));
    if need.is_none_or(|b| b > ratio * len) {
        let how = match compression {
            1 => "uncompressed",
            32773 => "PackBits",
            5 => "LZW",
            _ => "deflate",
        };
        let why = format!(
            "truncated or corrupt: the header declares {h} x {w} samples of {} bits, more \
             than a file of {len} bytes can hold ({how}{})",
            bits.unwrap_or(1),
            if ratio > 1 {
                format!(" expands at most {ratio}-fold")
            } else {
                String::new()
            }
        );
        return Ok((shape, Some(why)));
    }
    Ok((shape, None))
}

/// [`check_layout`]: the declared `(ny, nx)`, and why the image cannot be
/// read.
type Layout = (Option<(usize, usize)>, Option<String>);

/// The first image directory of a TIFF, classic or BigTIFF (TIFF 6.0 §2;
/// BigTIFF: 8-byte counts, values and offsets).
pub(super) struct Ifd {
    /// Little-endian (`II`) or big-endian (`MM`).
    pub le: bool,
    pub entries: Vec<Entry>,
}

/// One directory entry: its value field holds the values when they fit
/// (4 bytes, 8 in BigTIFF), else their offset.
pub(super) struct Entry {
    pub tag: u16,
    pub typ: u16,
    pub count: u64,
    pub field: Vec<u8>,
}

impl Ifd {
    /// `Ok(None)` for a file whose header is not a TIFF's (the decoder
    /// says why); `Err` when the directory lies or runs past the end of
    /// the file (`len` bytes).
    pub(super) fn read<R: Read + Seek>(
        r: &mut R,
        len: u64,
    ) -> std::result::Result<Option<Ifd>, String> {
        let mut head = [0u8; 16];
        let got = read_upto(r, &mut head);
        let le = match &head[..2] {
            b"II" => true,
            b"MM" => false,
            _ => return Ok(None),
        };
        let big = match (got >= 8).then(|| uint(&head[2..4], le)) {
            Some(42) => false,
            Some(43) if got >= 16 => true,
            _ => return Ok(None),
        };
        // classic: 12-byte entries after a 2-byte count; BigTIFF: 20-byte
        // entries after an 8-byte count
        let (word, count_w) = if big { (8, 8) } else { (4, 2) };
        let entry = 4 + 2 * word;
        let ifd = uint(if big { &head[8..16] } else { &head[4..8] }, le);
        let mut nbuf = [0u8; 8];
        if r.seek(SeekFrom::Start(ifd)).is_err() || read_upto(r, &mut nbuf[..count_w]) < count_w {
            return Err(format!(
                "the first image directory, at byte {ifd}, lies past the end of the file \
                 ({len} bytes)"
            ));
        }
        let n = uint(&nbuf[..count_w], le);
        let end = n
            .checked_mul(entry as u64)
            .and_then(|b| b.checked_add(ifd.checked_add(count_w as u64)?));
        if end.is_none_or(|e| e > len) {
            return Err(format!(
                "the first image directory ({n} entries at byte {ifd}) runs past the end of \
                 the file ({len} bytes)"
            ));
        }
        let mut raw = vec![0u8; n as usize * entry];
        if read_upto(r, &mut raw) < raw.len() {
            return Err(format!(
                "the first image directory at byte {ifd} cannot be read"
            ));
        }
        let entries = raw
            .chunks_exact(entry)
            .map(|e| Entry {
                tag: uint(&e[..2], le) as u16,
                typ: uint(&e[2..4], le) as u16,
                count: uint(&e[4..4 + word], le),
                field: e[4 + word..].to_vec(),
            })
            .collect();
        Ok(Some(Ifd { le, entries }))
    }

    /// The entry of `tag`, if any.
    pub(super) fn entry(&self, tag: u16) -> Option<&Entry> {
        self.entries.iter().find(|e| e.tag == tag)
    }
}

/// GeoTIFF 1.0 tags (OGC 19-008r4 §7): ModelPixelScale, ModelTiepoint,
/// ModelTransformation, GeoKeyDirectory.
const PIXEL_SCALE: u16 = 33550;
const TIEPOINT: u16 = 33922;
const TRANSFORMATION: u16 = 34264;
const GEO_KEYS: u16 = 34735;
const GEO_DOUBLES: u16 = 34736;

/// Projected systems (EPSG ProjectedCSTypeGeoKey) whose unit is the metre,
/// for GeoTIFFs that name the system but not ProjLinearUnitsGeoKey: the
/// UTM zones of WGS 84, WGS 72, NAD83, NAD27, ETRS89, GDA94 and GDA2020
/// (MGA), and national transverse Mercator and Lambert grids (Lambert-93,
/// British National Grid, NZTM, ETRS-TM35FIN, SWEREF99 TM, Swiss LV03 and
/// LV95, German Gauss-Krueger zones 2-5). Their map metres are ground
/// metres within a few parts per thousand. Continental equal-area and
/// polar projections, whose scale departs by percents, are left out, as
/// are systems in feet (US state planes): their units stay unknown.
fn metre_crs(code: u16) -> bool {
    matches!(
        code,
        32601..=32660   // WGS 84 / UTM north
            | 32701..=32760 // WGS 84 / UTM south
            | 32201..=32260 // WGS 72 / UTM north
            | 32301..=32360 // WGS 72 / UTM south
            | 26901..=26923 // NAD83 / UTM 1N-23N
            | 26703..=26722 // NAD27 / UTM 3N-22N
            | 25828..=25838 // ETRS89 / UTM 28N-38N
            | 28348..=28358 // GDA94 / MGA 48-58
            | 7846..=7859 // GDA2020 / MGA 46-59
            | 31466..=31469 // DHDN / 3-degree Gauss-Krueger 2-5
            | 2154 // RGF93 / Lambert-93
            | 27700 // OSGB36 / British National Grid
            | 2193 // NZGD2000 / NZTM
            | 3067 // ETRS89 / TM35FIN
            | 3006 // SWEREF99 TM
            | 21781 // CH1903 / LV03
            | 2056 // CH1903+ / LV95
    )
}

/// The pixel spacing a GeoTIFF declares (super::read_pixel_spacing):
/// ModelPixelScale, or the column lengths of an affine
/// ModelTransformation. Projected systems give their linear unit
/// (ProjLinearUnitsGeoKey, a user-defined unit's size in GeoDoubleParams,
/// or metres for the projected systems of [`metre_crs`]); geographic
/// ones (degrees, or the GeogAngularUnitsGeoKey) become metres at the
/// image's middle latitude, from the tiepoint. `Ok(None)` for a plain
/// TIFF, or tags this walk cannot use; a file that is not a readable TIFF
/// is left to the reader's error (also `Ok(None)`).
pub(super) fn pixel(path: &Path) -> Result<Option<super::georef::PixelSpacing>> {
    use super::georef::{PixelSpacing, geographic, linear_unit, sig, web_mercator};
    let file = std::fs::File::open(path).map_err(|source| Error::Read {
        path: path.into(),
        source,
    })?;
    let len = file.metadata().map(|m| m.len()).unwrap_or(0);
    let mut r = std::io::BufReader::new(file);
    let Ok(Some(ifd)) = Ifd::read(&mut r, len) else {
        return Ok(None);
    };
    let mut doubles = |tag| ifd.doubles(&mut r, len, tag);
    let scale = doubles(PIXEL_SCALE);
    let tie = doubles(TIEPOINT);
    let affine = doubles(TRANSFORMATION);
    let geo_doubles = doubles(GEO_DOUBLES);
    let dir = ifd.geo_key_directory(&mut r, len);
    let key = |k: u16| dir.iter().find(|e| e.0 == k && e.1 == 0).map(|e| e.3);
    // a key held in GeoDoubleParams (location 34736, one value at index v)
    let double_key = |k: u16| {
        dir.iter()
            .find(|e| e.0 == k && e.1 == GEO_DOUBLES && e.2 == 1)
            .and_then(|e| geo_doubles.as_ref()?.get(e.3 as usize).copied())
    };
    let first = |tag| {
        ifd.entry(tag)
            .and_then(|e| e.field.get(..type_size(e.typ)? as usize))
            .map(|s| uint(s, ifd.le) as f64)
    };
    let (Some(nx), Some(ny)) = (first(256), first(257)) else {
        return Ok(None);
    };
    // spacing, and the model y of the image's middle row and its span
    let (dx, dy, what, y_mid) = match (&scale, &affine) {
        (Some(s), _) if s.len() >= 2 => {
            let y_mid = tie
                .as_ref()
                .filter(|t| t.len() >= 6)
                .map(|t| t[4] - (ny / 2.0 - t[1]) * s[1]);
            // a negative scale (south-up writers) is a spacing all the same
            (s[0].abs(), s[1].abs(), "GeoTIFF ModelPixelScale", y_mid)
        }
        (_, Some(m)) if m.len() >= 16 => {
            let y_mid = m[4] * nx / 2.0 + m[5] * ny / 2.0 + m[7];
            (
                m[0].hypot(m[4]),
                m[1].hypot(m[5]),
                "GeoTIFF ModelTransformation",
                Some(y_mid),
            )
        }
        _ => return Ok(None),
    };
    if !(dx.is_finite() && dy.is_finite() && dx > 0.0 && dy > 0.0) {
        return Ok(None);
    }
    // GTModelTypeGeoKey: 1 projected, 2 geographic
    Ok(match key(1024) {
        Some(2) => {
            // GeogAngularUnitsGeoKey: degree (9102, the default; 9122, EPSG
            // 4326's "supplier to define"), radian (9101), arc-minute (9103),
            // arc-second (9104), grad and gon (9105, 9106)
            let per_degree = match key(2054).unwrap_or(9102) {
                9102 | 9122 => 1.0,
                9101 => std::f64::consts::PI / 180.0,
                9103 => 60.0,
                9104 => 3600.0,
                9105 | 9106 => 400.0 / 360.0,
                _ => return Ok(None),
            };
            let deg = |v: f64| v / per_degree;
            y_mid.and_then(|y| geographic(deg(dx), deg(dy), deg(y), deg(dy) * ny, what))
        }
        // Web Mercator (EPSG:3857 and its older codes): a pixel of the map
        // is about 1/cos(latitude) times its ground size (the sphere's
        // scale factor; on the WGS84 ellipsoid it differs by < 0.2 %)
        // (its sphere's radius is WGS84's semi-major axis)
        Some(1) if key(3072).is_some_and(|c| [3857, 3785].contains(&c)) => {
            y_mid.and_then(|y| web_mercator(dx, dy, y, ny, what))
        }
        Some(1) => {
            // ProjLinearUnitsGeoKey (EPSG unit codes; 32767 user-defined,
            // its metres in ProjLinearUnitSizeGeoKey 3077), else the
            // metres of a well-known ProjectedCSTypeGeoKey
            let factor = match key(3076) {
                Some(9001) => Some(1.0),
                Some(9002) => Some(0.3048),
                Some(9003) => Some(1200.0 / 3937.0),
                Some(9036) => Some(1000.0),
                Some(32767) => double_key(3077).filter(|f| f.is_finite() && *f > 0.0),
                Some(_) => None,
                None => key(3072).filter(|&c| metre_crs(c)).map(|_| 1.0),
            };
            let plain = |x: f64, y: f64, units: Option<String>, note: String| PixelSpacing {
                x,
                y,
                source: format!("{what} {} x {}{note}", sig(dx), sig(dy)),
                units,
                warnings: Vec::new(),
            };
            Some(match factor {
                Some(f) => match linear_unit(f) {
                    Some(u) => plain(dx, dy, Some(u.into()), String::new()),
                    // a unit wtmm does not name: in metres, as from a .prj
                    None => plain(
                        dx * f,
                        dy * f,
                        Some("m".into()),
                        format!(" (a unit of {} m)", sig(f)),
                    ),
                },
                None => plain(dx, dy, None, " (projected, units not understood)".into()),
            })
        }
        // no model type key (or geocentric): the spacing, units unknown
        _ => Some(PixelSpacing {
            x: dx,
            y: dy,
            units: None,
            source: format!(
                "{what} {} x {} (no model type in the GeoKeys: units unknown)",
                sig(dx),
                sig(dy)
            ),
            warnings: Vec::new(),
        }),
    })
}

impl Ifd {
    /// The DOUBLE values of `tag`, if it has at most 64 of them, all inside
    /// the file.
    fn doubles<R: Read + Seek>(&self, r: &mut R, len: u64, tag: u16) -> Option<Vec<f64>> {
        let e = self.entry(tag).filter(|e| e.typ == 12 && e.count <= 64)?;
        let b = self.values(r, len, e)?;
        Some(
            b.chunks_exact(8)
                .map(|c| f64::from_bits(uint(c, self.le)))
                .collect(),
        )
    }

    /// The GeoKeyDirectory's keys as `(KeyID, TIFFTagLocation, Count,
    /// Value_Offset)` (GeoTIFF §7.1.3): the value itself for location 0,
    /// else an index into the tag at that location.
    fn geo_key_directory<R: Read + Seek>(&self, r: &mut R, len: u64) -> Vec<(u16, u16, u16, u16)> {
        let Some(b) = self
            .entry(GEO_KEYS)
            .filter(|e| e.typ == 3 && e.count <= 4 * 1024)
            .and_then(|e| self.values(r, len, e))
        else {
            return Vec::new();
        };
        let w: Vec<u16> = b.chunks_exact(2).map(|c| uint(c, self.le) as u16).collect();
        let n = w.get(3).copied().unwrap_or(0) as usize;
        w[4.min(w.len())..]
            .chunks_exact(4)
            .take(n)
            .map(|k| (k[0], k[1], k[2], k[3]))
            .collect()
    }

    /// The bytes of an entry's values: in the entry, or at its offset when
    /// they lie inside the file.
    fn values<R: Read + Seek>(&self, r: &mut R, len: u64, e: &Entry) -> Option<Vec<u8>> {
        let n = e.count.checked_mul(type_size(e.typ)?)?;
        if n <= e.field.len() as u64 {
            return Some(e.field[..n as usize].to_vec());
        }
        let at = uint(&e.field, self.le);
        if at.checked_add(n)? > len {
            return None;
        }
        r.seek(SeekFrom::Start(at)).ok()?;
        let mut b = vec![0u8; n as usize];
        (read_upto(r, &mut b) == b.len()).then_some(b)
    }
}

/// Bytes per value of a field type (TIFF 6.0 §2; BigTIFF 16-18); `None`
/// for a type neither knows.
pub(super) fn type_size(typ: u16) -> Option<u64> {
    match typ {
        1 | 2 | 6 | 7 => Some(1),
        3 | 8 => Some(2),
        4 | 9 | 11 | 13 => Some(4),
        5 | 10 | 12 | 16 | 17 | 18 => Some(8),
        _ => None,
    }
}

/// An unsigned integer from its bytes (at most 8) in the file's byte order.
pub(super) fn uint(s: &[u8], le: bool) -> u64 {
    let mut v = 0u64;
    for k in 0..s.len() {
        v = v << 8 | s[if le { s.len() - 1 - k } else { k }] as u64;
    }
    v
}

/// Reads into `buf` until it is full or the reader ends; the bytes read.
fn read_upto<R: Read>(r: &mut R, buf: &mut [u8]) -> usize {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..]) {
            Ok(0) | Err(_) => break,
            Ok(k) => got += k,
        }
    }
    got
}

/// Rewrites a PhotometricInterpretation of 0 (WhiteIsZero) in the first
/// IFD to 1 (BlackIsZero), in place; true if it did. The decoder offers no
/// switch for its inversion and no tag offsets, so the IFD is walked here
/// (classic and BigTIFF, either byte order); anything out of bounds leaves
/// the bytes alone for the decoder to report.
fn patch_white_is_zero(b: &mut [u8]) -> bool {
    let le = match b.get(..2) {
        Some(b"II") => true,
        Some(b"MM") => false,
        _ => return false,
    };
    let uint = |b: &[u8], at: usize, n: usize| -> Option<u64> {
        Some(uint(b.get(at..at.checked_add(n)?)?, le))
    };
    // classic: the first IFD's offset (4 bytes) at byte 4, a 2-byte entry
    // count, 12-byte entries with the value at byte 8; BigTIFF: 8 bytes at
    // byte 8, an 8-byte count, 20-byte entries with the value at byte 12
    let (ifd_at, off_w, count_w, entry, value_at) = match uint(b, 2, 2) {
        Some(42) => (4, 4, 2, 12, 8),
        Some(43) => (8, 8, 8, 20, 12),
        _ => return false,
    };
    let Some(ifd) = uint(b, ifd_at, off_w).and_then(|v| usize::try_from(v).ok()) else {
        return false;
    };
    let Some(n) = uint(b, ifd, count_w).and_then(|v| usize::try_from(v).ok()) else {
        return false;
    };
    for i in 0..n.min(4096) {
        let Some(e) = (i * entry).checked_add(ifd + count_w) else {
            return false;
        };
        let Some(tag) = uint(b, e, 2) else {
            return false;
        };
        // tag 262 of type SHORT (3): its value sits in the entry itself
        if tag == 262 && uint(b, e + 2, 2) == Some(3) {
            if uint(b, e + value_at, 2) == Some(0) {
                let one = if le { [1, 0] } else { [0, 1] };
                b[e + value_at..e + value_at + 2].copy_from_slice(&one);
                return true;
            }
            return false;
        }
    }
    false
}

/// Encodes a one-band float32 TIFF in memory.
pub(super) fn encode_f32(path: &Path, a: &Array2<f64>) -> Result<Vec<u8>> {
    let (ny, nx) = a.dim();
    if ny == 0 || nx == 0 {
        return Err(Error::format(
            path,
            format!("cannot write an empty image ({ny} x {nx})"),
        ));
    }
    let (w, h) = match (u32::try_from(nx), u32::try_from(ny)) {
        (Ok(w), Ok(h)) => (w, h),
        _ => return Err(Error::format(path, "image too large for TIFF")),
    };
    // float32 holds |v| in [1.2e-38, 3.4e38] at full precision: refuse what
    // it would turn into inf (read back as missing) or flush whole to 0
    let big = a
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    if big > f32::MAX as f64 || (big > 0.0 && big < f32::MIN_POSITIVE as f64) {
        return Err(Error::format(
            path,
            format!(
                "values up to {big:e} in magnitude do not fit a float32 TIFF \
                 (1.2e-38 to 3.4e38): write .npy (float64) or rescale"
            ),
        ));
    }
    let data: Vec<f32> = a.iter().map(|&v| v as f32).collect();
    let err = |e: tiff::TiffError| Error::format(path, format!("cannot encode TIFF: {e}"));
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).map_err(err)?;
        let mut img = enc.new_image::<colortype::Gray32Float>(w, h).map_err(err)?;
        if data.iter().any(|v| v.is_nan()) {
            // Lets GDAL and QGIS see the NaN pixels as missing too.
            img.encoder()
                .write_tag(Tag::GdalNodata, "nan")
                .map_err(err)?;
        }
        img.write_data(&data).map_err(err)?;
    }
    Ok(buf.into_inner())
}
