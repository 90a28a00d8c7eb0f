//! Memory planning: what a command may use, and how many images fit at once.

use super::*;

/// The environment variable that sets the memory wtmm plans for, in GB.
pub const MEMORY_VAR: &str = "WTMM_MEMORY_GB";

/// The memory a command may use, in bytes: `WTMM_MEMORY_GB` when set (a
/// share of a machine others use too), else [`system_memory`]. `None`
/// where neither can be read (not Linux). A bad `WTMM_MEMORY_GB` reads as
/// unset here: [`check_memory_variable`] refuses it when a command starts.
pub fn available_memory() -> Option<f64> {
    match memory_variable() {
        Ok(Some(b)) => Some(b),
        _ => system_memory(),
    }
}

/// `MemAvailable` of /proc/meminfo, within the process's cgroup memory
/// limit when it has one (a container, a batch job: beyond the limit the
/// process is killed with no message, while /proc/meminfo still shows the
/// host's memory), in bytes.
pub fn system_memory() -> Option<f64> {
    memory_sources().0
}

/// [`system_memory`], and whether the cgroup's limit is what bounds it.
fn memory_sources() -> (Option<f64>, bool) {
    let host = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| meminfo_available(&s));
    match (host, cgroup_headroom()) {
        (Some(h), Some(c)) => (Some(h.min(c)), c < h),
        (h, c) => (h.or(c), h.is_none() && c.is_some()),
    }
}

/// `WTMM_MEMORY_GB` in bytes, `None` when unset (or set empty).
fn memory_variable() -> Result<Option<f64>> {
    let Some(v) = std::env::var_os(MEMORY_VAR) else {
        return Ok(None);
    };
    let s = v.to_string_lossy();
    if s.trim().is_empty() {
        return Ok(None);
    }
    match s.trim().parse::<f64>() {
        Ok(gb) if gb.is_finite() && gb > 0.0 => Ok(Some(gb * 1e9)),
        _ => Err(Error::param(
            MEMORY_VAR,
            format!(
                "the environment variable must be a positive number of GB (unset, the memory \
                 the system reports is used), not `{s}`"
            ),
        )),
    }
}

/// Refuses a `WTMM_MEMORY_GB` that is not a positive number, before a
/// command starts.
pub fn check_memory_variable() -> Result<()> {
    memory_variable().map(|_| ())
}

/// `X GB are available`, `... (the cgroup's limit; WTMM_MEMORY_GB sets
/// another)` when a container's or job's limit bounds it, or `X GB are
/// allowed (WTMM_MEMORY_GB)` when the budget is the variable's, for the
/// memory messages.
pub fn gb_available(avail: f64) -> String {
    let set = matches!(memory_variable(), Ok(Some(_)));
    let why = if set {
        "allowed (WTMM_MEMORY_GB)"
    } else if memory_sources().1 {
        "available (the limit of this process's memory cgroup, a container or a job; \
         WTMM_MEMORY_GB sets another)"
    } else {
        "available"
    };
    format!("{} are {why}", memory_text(avail))
}

/// `bytes` for a memory message: `1.2 GB`, or `350 MB` below 1 GB (where
/// one decimal of a GB would say 0.0).
pub fn memory_text(bytes: f64) -> String {
    if bytes < 0.95e9 {
        format!("{:.0} MB", bytes / 1e6)
    } else {
        format!("{:.1} GB", bytes / 1e9)
    }
}

/// `MemAvailable` of a /proc/meminfo text, in bytes.
pub(super) fn meminfo_available(meminfo: &str) -> Option<f64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

/// What the memory cgroup of this process leaves before its limit, in
/// bytes: the lowest headroom of its group and their ancestors' (a job's
/// limit binds its steps), each `limit - (usage - file cache)`, the page
/// cache of files counting as free, as `MemAvailable` counts it (re-read
/// files move to the active list, which the kernel reclaims too). `None`
/// without a limit, or where none can be read.
fn cgroup_headroom() -> Option<f64> {
    let own = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    cgroup_headroom_in(&own, Path::new("/sys/fs/cgroup"))
}

/// [`cgroup_headroom`] of the groups `own` (a /proc/self/cgroup text)
/// under the cgroup mount `root`.
pub(super) fn cgroup_headroom_in(own: &str, root: &Path) -> Option<f64> {
    let read = |p: &Path| std::fs::read_to_string(p).ok();
    // v1: a `memory` hierarchy of its own; v2: the unified one (`0::`)
    let (base, path, files) = match cgroup_path(own, "memory") {
        Some(path) => (
            root.join("memory"),
            path,
            ["memory.limit_in_bytes", "memory.usage_in_bytes"],
        ),
        None => (
            root.to_path_buf(),
            cgroup_path(own, "")?,
            ["memory.max", "memory.current"],
        ),
    };
    // the cache keys of memory.stat: v1 counts the group's subtree in
    // total_*, v2 in the plain keys
    let cache_keys: &[&str] = if files[0] == "memory.max" {
        &["active_file", "inactive_file"]
    } else {
        &["total_active_file", "total_inactive_file"]
    };
    // inside a cgroup namespace the own group is the mount's root, and the
    // path read is not under it
    let own_dir = base.join(path.trim_start_matches('/'));
    let start = if own_dir.exists() {
        own_dir
    } else {
        base.clone()
    };
    let mut best: Option<f64> = None;
    let mut dir = Some(start.as_path());
    while let Some(d) = dir.filter(|d| d.starts_with(&base)) {
        // a level without the files (a v2 group whose parent does not
        // enable the memory controller, the v2 root) is passed over
        if let (Some(limit), Some(usage)) = (read(&d.join(files[0])), read(&d.join(files[1]))) {
            let cache: f64 = read(&d.join("memory.stat")).map_or(0.0, |st| {
                cache_keys.iter().filter_map(|k| stat_value(&st, k)).sum()
            });
            let h = limit
                .trim()
                .parse()
                .ok()
                .and_then(|l: f64| headroom(l, usage.trim().parse().ok()?, cache));
            if let Some(h) = h {
                best = Some(best.map_or(h, |b| b.min(h)));
            }
        }
        dir = d.parent();
    }
    best
}

/// The group's path in a /proc/self/cgroup text for the v1 `controller`
/// (`""`: the v2 unified hierarchy, `0::/path`).
pub(super) fn cgroup_path<'a>(own: &'a str, controller: &str) -> Option<&'a str> {
    own.lines().find_map(|l| {
        let mut f = l.splitn(3, ':');
        let (_, list, path) = (f.next()?, f.next()?, f.next()?);
        let hit = if controller.is_empty() {
            list.is_empty()
        } else {
            list.split(',').any(|c| c == controller)
        };
        hit.then_some(path)
    })
}

/// The value of `key` in a memory.stat text.
pub(super) fn stat_value(stat: &str, key: &str) -> Option<f64> {
    stat.lines().find_map(|l| {
        let (k, v) = l.split_once(' ')?;
        (k == key).then(|| v.trim().parse().ok()).flatten()
    })
}

/// A limit's headroom over a usage of which `cache` bytes are
/// reclaimable; `None` for no limit (v1 writes "no limit" as about 2^63,
/// v2 as "max", which does not parse).
pub(super) fn headroom(limit: f64, usage: f64, cache: f64) -> Option<f64> {
    (limit < 2f64.powi(60)).then(|| (limit - (usage - cache).max(0.0)).max(0.0))
}

/// Bytes per pixel of the WTMM analysis of one image on one thread (the
/// image, the half spectrum, one full-plane transform workspace, the
/// per-scale maxima), what an image with missing pixels adds (its filled
/// copy, the mask and the distance to it: +16 B/px measured with a 200 x
/// 300 hole in 2048^2; without a mask the image itself is transformed), and what each
/// further thread adds when a lone image's scales run in parallel: peak RSS
/// of `analyze` on fBm 2048^2 and 4096^2, 2026-11-26, 52 B/px on one thread
/// (60-62 with the copy every image had before), 76-85 on two.
const ANALYSIS_BYTES_PER_PIXEL: f64 = 54.0;
const ANALYSIS_BYTES_PER_PIXEL_MASKED: f64 = 16.0;
const ANALYSIS_BYTES_PER_PIXEL_PER_THREAD: f64 = 28.0;

/// What each image in flight of an ensemble analysed one image per worker
/// (analyze, pdf, kernel; correlate needs more) needs per pixel, planned from the
/// files' headers before they are read, so counting the masked image's
/// extra: whether an image has missing pixels is known once read.
pub const ENSEMBLE_ANALYSIS_BYTES_PER_PIXEL: f64 =
    ANALYSIS_BYTES_PER_PIXEL + ANALYSIS_BYTES_PER_PIXEL_MASKED;

/// Refuses, before its transform, an image whose analysis cannot fit in
/// the available memory (a 16384^2 DEM needs about 15 GB on one thread):
/// the allocation would abort the process with no message. `lone`: the
/// image is analysed alone, its scales on every thread.
pub fn check_image_memory(path: &Path, field: &Field, lone: bool) -> Result<()> {
    let threads = if lone {
        rayon::current_num_threads().max(1)
    } else {
        1
    };
    let (ny, nx) = field.dim();
    let masked = field.mask.is_some();
    match available_memory().and_then(|avail| image_memory_problem(ny, nx, masked, threads, avail))
    {
        Some(why) => Err(Error::format(path, why)),
        None => Ok(()),
    }
}

/// What [`check_image_memory`] says when `avail` bytes are too few.
pub(super) fn image_memory_problem(
    ny: usize,
    nx: usize,
    masked: bool,
    threads: usize,
    avail: f64,
) -> Option<String> {
    let px = (ny * nx) as f64;
    let one = ANALYSIS_BYTES_PER_PIXEL
        + if masked {
            ANALYSIS_BYTES_PER_PIXEL_MASKED
        } else {
            0.0
        };
    let per_px = one + ANALYSIS_BYTES_PER_PIXEL_PER_THREAD * (threads - 1) as f64;
    let need = per_px * px;
    (need > avail).then(|| {
        format!(
            "analysing this {ny}x{nx} image needs about {:.1} GB of memory{}",
            need / 1e9,
            memory_tail(threads, avail, one * px)
        )
    })
}

/// What a memory refusal says after the need: ` (N threads), X GB are
/// available`, and with several threads what one would need
/// (`one_thread` bytes).
fn memory_tail(threads: usize, avail: f64, one_thread: f64) -> String {
    format!(
        " ({threads} thread{}), {}{}",
        if threads == 1 { "" } else { "s" },
        gb_available(avail),
        if threads > 1 {
            format!(
                " (on one thread, RAYON_NUM_THREADS=1, about {:.1} GB)",
                one_thread / 1e9
            )
        } else {
            String::new()
        }
    )
}

/// Peak memory of `tm` on one or two images, whose errors come from tiles
/// (the whole image and its tiles, `TraceMomentAccumulator::field_tiles`),
/// per pixel of the images, from peak RSS of `tm` on fBm 2048^2 and
/// 4096^2 (2026-11-29): 141-143 B/px on one thread, 178-179 on two (the
/// whole image beside its tiles, the double trace moments' eta in two
/// halves), 219 on 16 at 2048^2 (those two splits bound the tasks: threads
/// beyond three add nothing); a 200 x 300 hole in 4096^2 changed it by
/// less than 1 B/px.
const TM_TILES_BYTES_PER_PIXEL: f64 = 143.0;
const TM_TILES_BYTES_PER_PIXEL_PER_THREAD: f64 = 38.0;
const TM_TILES_EXTRA_THREADS: usize = 2;

/// Refuses, before any image is read, the trace moments of one or two
/// images (`px` pixels in all; `largest`: the path and shape of the
/// largest, named in the message) that the available memory cannot hold:
/// the allocation would abort the process with no message.
pub fn check_tm_memory(largest: (&Path, usize, usize), px: usize) -> Result<()> {
    let threads = rayon::current_num_threads().max(1);
    let why = available_memory()
        .and_then(|avail| tm_memory_problem(largest.1, largest.2, px, threads, avail));
    why.map_or(Ok(()), |w| Err(Error::format(largest.0, w)))
}

/// What [`check_tm_memory`] says when `avail` bytes are too few.
pub(super) fn tm_memory_problem(
    ny: usize,
    nx: usize,
    px: usize,
    threads: usize,
    avail: f64,
) -> Option<String> {
    let extra = (threads - 1).min(TM_TILES_EXTRA_THREADS) as f64;
    let need = (TM_TILES_BYTES_PER_PIXEL + TM_TILES_BYTES_PER_PIXEL_PER_THREAD * extra) * px as f64;
    (need > avail).then(|| {
        format!(
            "the trace moments of this {ny}x{nx} image{} need about {:.1} GB of memory{}; crop \
             it, or tile it into several images (an ensemble of three or more is analysed one \
             image per thread)",
            if px > ny * nx { " and the other" } else { "" },
            need / 1e9,
            memory_tail(threads, avail, TM_TILES_BYTES_PER_PIXEL * px as f64)
        )
    })
}

/// Peak memory of `tm` per image in flight in an ensemble of three or more
/// (one image per worker, dropped after its sums), per pixel: peak RSS of
/// `tm` on fBm planes (2026-11-29), 3 x 4096^2: 2.47 GB on one thread
/// (147 B/px), 4.35 GB on two (130 B/px per image in flight); 4 x 2048^2:
/// 0.68 and 1.19 GB (144 and 134 B/px above the 73 MB of the process);
/// one image in flight on two threads, its double trace moments' two
/// halves side by side (a memory-limited run): 0.82 GB, 179 B/px.
pub const TM_ENSEMBLE_BYTES_PER_PIXEL: f64 = 190.0;

/// How many workers, of at most `threads`, can hold images of `px` pixels
/// side by side at `per_px` bytes per pixel within `avail` bytes: the most
/// whose largest images fit together (0 when not even the largest fits).
pub(super) fn workers_that_fit(px: &[usize], per_px: f64, threads: usize, avail: f64) -> usize {
    let mut px = px.to_vec();
    px.sort_unstable_by(|a, b| b.cmp(a));
    let mut need = 0.0;
    px.iter()
        .take(threads)
        .take_while(|&&p| {
            need += per_px * p as f64;
            need <= avail
        })
        .count()
}

/// How many images of the ensemble `paths` (of sizes `sizes`, from their
/// headers), held one per worker at `per_px` bytes per pixel, the
/// available memory holds side by side (the largest ones): `Some(workers)`
/// when fewer than rayon has threads (said in a note; the caller's pass
/// then runs its images on that many threads,
/// [`crate::par::try_map_at_limited`]), `None` when every thread can hold
/// one: on 16 threads, 16 DEMs of 8192^2 in flight would abort the process
/// with no message. The results do not depend on the thread count. `what`
/// names the pass ("the trace moments").
///
/// **Errors**, before any image is read, when not even the largest image
/// fits alone (the message names it).
pub fn memory_workers(
    paths: &[PathBuf],
    sizes: &[[usize; 2]],
    per_px: f64,
    what: &str,
) -> Result<Option<usize>> {
    let threads = rayon::current_num_threads().max(1);
    let Some(avail) = available_memory() else {
        return Ok(None);
    };
    let px: Vec<usize> = sizes.iter().map(|[ny, nx]| ny * nx).collect();
    let fit = workers_that_fit(&px, per_px, threads, avail);
    if fit >= threads.min(px.len()) {
        return Ok(None);
    }
    let Some(big) = (0..px.len()).max_by_key(|&i| (px[i], std::cmp::Reverse(i))) else {
        return Ok(None);
    };
    let [ny, nx] = sizes[big];
    let one = per_px * px[big] as f64;
    if fit == 0 {
        return Err(Error::format(
            &paths[big],
            format!(
                "this {ny}x{nx} image needs about {} of memory for {what}, {}; crop it, or \
                 tile it into several images",
                memory_text(one),
                gb_available(avail)
            ),
        ));
    }
    say_fewer_workers(what, fit, threads, (ny, nx), one, avail);
    Ok(Some(fit))
}

/// The note of a pass run on `fit` of `threads` threads because an image
/// of `shape` in flight needs `need` bytes of the `avail` available.
fn say_fewer_workers(
    what: &str,
    fit: usize,
    threads: usize,
    (ny, nx): (usize, usize),
    need: f64,
    avail: f64,
) {
    say!(
        "note: {what} on {fit} of {threads} threads: an image of {ny}x{nx} in flight \
         needs about {} of memory and {} (the results are the same on any thread count)",
        memory_text(need),
        gb_available(avail)
    );
}

/// [`memory_workers`] of the image files `paths`, their sizes read from
/// their headers; `None` for fewer than two (a lone image is checked with
/// its threads once read).
pub fn ensemble_memory_workers(
    paths: &[PathBuf],
    per_px: f64,
    what: &str,
) -> Result<Option<usize>> {
    if paths.len() < 2 {
        return Ok(None);
    }
    let sizes = paths
        .iter()
        .map(crate::io::read_shape)
        .collect::<Result<Vec<_>>>()?;
    memory_workers(paths, &sizes, per_px, what)
}

/// Bytes per pixel beyond the images already read: `spectrum` per image in
/// flight (its filled and detrended copies and FFT, one per worker), `cwt`
/// for its one image (the transform's scales in flight and their files'
/// buffers). From peak RSS, 2026-11-26: spectrum 41 B/px in all for one
/// image of 2048^2 or 4096^2, 8 of them the image; 4 x 2048^2 gave 405 MB
/// on two threads and 274 MB on one, as 8 B/px held per image plus 33 per
/// image in flight; cwt 79-85 B/px in all (4 scales at 4096^2, 8 at
/// 2048^2, one or two threads).
const SPECTRUM_BYTES_PER_PIXEL_IN_FLIGHT: f64 = 33.0;
const CWT_BYTES_PER_PIXEL_BEYOND_IMAGE: f64 = 77.0;

/// What the image `path` of `ny x nx` will need beyond what is read, for
/// `what` ("its power spectrum", "its transform") with `copies` in flight
/// (the workers of `spectrum`), against `avail` bytes: the message when it
/// is too much.
pub(super) fn extra_memory_problem(
    what: &str,
    ny: usize,
    nx: usize,
    per_px: f64,
    copies: usize,
    avail: f64,
) -> Option<String> {
    let need = per_px * (ny * nx) as f64 * copies as f64;
    (need > avail).then(|| {
        format!(
            "{what} of this {ny}x{nx} image needs about {:.1} GB of memory beyond the images \
             read ({copies} in flight), {}{}",
            need / 1e9,
            gb_available(avail),
            if copies > 1 {
                " (one at a time with RAYON_NUM_THREADS=1)"
            } else {
                ""
            }
        )
    })
}

/// Refuses, before its FFTs, the power spectrum of images the available
/// memory cannot hold in flight (`largest`: the path and shape of the
/// largest image; `n`: how many there are): the allocation would abort
/// the process with no message.
pub fn check_spectrum_memory(largest: (&Path, usize, usize), n: usize) -> Result<()> {
    let (path, ny, nx) = largest;
    let copies = rayon::current_num_threads().max(1).min(n.max(1));
    let why = available_memory().and_then(|avail| {
        extra_memory_problem(
            "the power spectrum",
            ny,
            nx,
            SPECTRUM_BYTES_PER_PIXEL_IN_FLIGHT,
            copies,
            avail,
        )
    });
    why.map_or(Ok(()), |w| Err(Error::format(path, w)))
}

/// [`check_spectrum_memory`] for `cwt`'s one image.
pub fn check_cwt_memory(path: &Path, ny: usize, nx: usize) -> Result<()> {
    let why = available_memory().and_then(|avail| {
        extra_memory_problem(
            "the transform",
            ny,
            nx,
            CWT_BYTES_PER_PIXEL_BEYOND_IMAGE,
            1,
            avail,
        )
    });
    why.map_or(Ok(()), |w| Err(Error::format(path, w)))
}

/// Bytes per pixel of one generated image in flight in `validate` or
/// `compare` (generator, power spectrum, transform and skeleton,
/// correlation or trace moments), from peak RSS with two threads,
/// 2026-11-26: validate 114 (log-normal), 184 (fBm) and 200 (FISC) at
/// 2048^2, 139 (FISC) at 4096^2; compare 160 (log-normal, fBm) at 2048^2.
const ENSEMBLE_BYTES_PER_PIXEL: f64 = 200.0;

/// Sizes up front a generated ensemble's images in flight (one per worker)
/// to the available memory: the allocation would abort the process with no
/// message and the output directory half made. `Some(workers)`: run on
/// that many images at once ([`crate::par::try_map_limited`]; said in a
/// note); refused when not even one image fits. For `validate` and
/// `compare`.
pub fn check_ensemble_memory(size: usize, count: usize, what: &str) -> Result<Option<usize>> {
    check_memory(size, count, ENSEMBLE_BYTES_PER_PIXEL, what)
}

/// [`check_memory`] for the generated images of `pdf`, `kernel` and
/// `correlate` with a model: `per_px` for the analysis, at least what
/// `validate` takes per image (generator, transform, skeleton and
/// correlation: [`ENSEMBLE_BYTES_PER_PIXEL`]).
pub fn check_generated_memory(
    size: usize,
    count: usize,
    per_px: f64,
    what: &str,
) -> Result<Option<usize>> {
    check_memory(size, count, per_px.max(ENSEMBLE_BYTES_PER_PIXEL), what)
}

/// Size and count of a generated ensemble (`validate`, `compare`, `demo`,
/// and `pdf`, `kernel`, `correlate` with a model): the sizes `synth`
/// writes, and at most [`crate::cli::synth_cmd::MAX_COUNT`] images (the
/// per-image sums of the jackknife grow with the count; a larger study is
/// several runs with different --seed).
pub fn check_generated(size: usize, count: usize) -> Result<()> {
    check_generated_side(size)?;
    let max = crate::cli::synth_cmd::MAX_COUNT;
    if count == 0 {
        return Err(Error::param("count", "must be >= 1"));
    }
    if count > max {
        return Err(Error::param(
            "count",
            format!(
                "must be at most {max}, got {count} (a larger study: several runs with \
                 different --seed)"
            ),
        ));
    }
    Ok(())
}

/// The side of a generated image: 16 px (the smallest worth analysing) to
/// 16384 px, the square root of the pixel limit of the readers and
/// generators (`io::MAX_PIXELS`).
pub fn check_generated_side(size: usize) -> Result<()> {
    let max = (crate::io::MAX_PIXELS as f64).sqrt() as usize;
    if !(16..=max).contains(&size) {
        return Err(Error::param(
            "size",
            format!("must be in 16..={max}, got {size}"),
        ));
    }
    Ok(())
}

/// [`check_ensemble_memory`] with `bytes_per_pixel` per image in flight
/// (`synth`: 64, its fBm grid).
pub fn check_memory(
    size: usize,
    count: usize,
    bytes_per_pixel: f64,
    what: &str,
) -> Result<Option<usize>> {
    let per_image = bytes_per_pixel * (size as f64).powi(2);
    let threads = rayon::current_num_threads().max(1);
    let Some(avail) = available_memory() else {
        return Ok(None);
    };
    let fit = (avail / per_image).floor() as usize;
    if fit == 0 {
        return Err(Error::param(
            "size",
            format!(
                "{size} px needs about {} in memory for one image; {} (a smaller --size)",
                memory_text(per_image),
                gb_available(avail)
            ),
        ));
    }
    Ok((fit < count.min(threads)).then(|| {
        say_fewer_workers(what, fit, threads, (size, size), per_image, avail);
        fit
    }))
}
