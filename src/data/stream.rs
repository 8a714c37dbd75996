//! Views read from disk on demand (`data.cache_mb`), for captures whose decoded images do not
//! fit in memory.
//!
//! A streamed view keeps only how to decode its image (a closure over the file path and the
//! reader's post-processing). Decoded images live in a [`FrameCache`] shared by the dataset: a
//! least-recently-used cache bounded in bytes. The training sampler asks for the next views of
//! its order ahead of time ([`ViewImage::prefetch`]); a background thread decodes them into the
//! cache, so that an iteration rarely waits for the disk.

use std::collections::{HashMap, HashSet};
use std::fmt;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Sender, channel};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, Weak};

use image::RgbImage;

use super::DataError;

/// Decodes one view's image (reading its file and applying the reader's downscaling).
pub type DecodeImage = dyn Fn() -> Result<RgbImage, DataError> + Send + Sync;

/// The pixels of a view: decoded in memory, or decoded on demand through a [`FrameCache`].
#[derive(Clone)]
pub enum ViewImage {
    /// Decoded once when the dataset was read.
    Memory(Arc<RgbImage>),
    /// Read from disk when needed.
    Streamed(StreamedImage),
}

/// A view image read through a cache.
#[derive(Clone)]
pub struct StreamedImage {
    key: u64,
    /// The file it is read from (for errors).
    path: Arc<Path>,
    width: u32,
    height: u32,
    decode: Arc<DecodeImage>,
    cache: Arc<FrameCache>,
}

impl From<RgbImage> for ViewImage {
    fn from(image: RgbImage) -> Self {
        Self::Memory(Arc::new(image))
    }
}

/// Same pixels (an image that cannot be read equals nothing).
impl PartialEq<RgbImage> for ViewImage {
    fn eq(&self, other: &RgbImage) -> bool {
        self.dimensions() == other.dimensions() && self.pixels().is_ok_and(|image| *image == *other)
    }
}

/// Same pixels (an image that cannot be read equals nothing).
impl PartialEq for ViewImage {
    fn eq(&self, other: &Self) -> bool {
        other.pixels().is_ok_and(|image| *self == *image)
    }
}

impl fmt::Debug for ViewImage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (width, height) = self.dimensions();
        let kind = match self {
            Self::Memory(_) => "in memory",
            Self::Streamed(_) => "streamed",
        };
        write!(f, "ViewImage({width}×{height}, {kind})")
    }
}

impl ViewImage {
    /// An image of `width × height` pixels that `decode` reads from `path` when needed, held
    /// in `cache`. `decode` must return an image of that size.
    pub fn streamed(
        path: &Path,
        (width, height): (u32, u32),
        cache: &Arc<FrameCache>,
        decode: impl Fn() -> Result<RgbImage, DataError> + Send + Sync + 'static,
    ) -> Self {
        Self::Streamed(StreamedImage {
            key: NEXT_KEY.fetch_add(1, Ordering::Relaxed),
            path: path.into(),
            width,
            height,
            decode: Arc::new(decode),
            cache: cache.clone(),
        })
    }

    /// Width and height in pixels (known without decoding).
    pub fn dimensions(&self) -> (u32, u32) {
        match self {
            Self::Memory(image) => image.dimensions(),
            Self::Streamed(s) => (s.width, s.height),
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.dimensions().0
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.dimensions().1
    }

    /// The decoded image: at once when in memory or cached, otherwise read from disk (and
    /// kept in the cache while it has room).
    pub fn pixels(&self) -> Result<Arc<RgbImage>, DataError> {
        match self {
            Self::Memory(image) => Ok(image.clone()),
            Self::Streamed(s) => {
                let image = s.cache.get(s.key, &*s.decode)?;
                if image.dimensions() != (s.width, s.height) {
                    return Err(DataError::Size {
                        path: s.path.to_path_buf(),
                        width: s.width,
                        height: s.height,
                        found_width: image.width(),
                        found_height: image.height(),
                    });
                }
                Ok(image)
            }
        }
    }

    /// Asks the cache to decode this image in the background if it does not hold it (a no-op
    /// for an image in memory).
    pub fn prefetch(&self) {
        if let Self::Streamed(s) = self {
            s.cache.prefetch(s.key, &s.decode);
        }
    }

    /// The same pixels transformed by `map` (e.g. downscaled): in memory, transformed now; streamed,
    /// transformed after each decode, through the same cache under a key of its own.
    pub fn map(
        &self,
        size: (u32, u32),
        map: impl Fn(&RgbImage) -> RgbImage + Send + Sync + 'static,
    ) -> Self {
        match self {
            Self::Memory(image) => Self::from(map(image)),
            Self::Streamed(s) => {
                let inner = s.decode.clone();
                Self::streamed(&s.path, size, &s.cache, move || Ok(map(&inner()?)))
            }
        }
    }

    /// Bytes this view holds itself (a streamed view's pixels count in its cache instead).
    pub fn resident_bytes(&self) -> usize {
        match self {
            Self::Memory(image) => image.as_raw().len(),
            Self::Streamed(_) => 0,
        }
    }

    /// The cache a streamed image is read through.
    pub fn cache(&self) -> Option<&Arc<FrameCache>> {
        match self {
            Self::Memory(_) => None,
            Self::Streamed(s) => Some(&s.cache),
        }
    }
}

/// Keys of streamed images, unique in the process (so caches may be shared between datasets).
static NEXT_KEY: AtomicU64 = AtomicU64::new(0);

/// Decoded images held for streamed views, at most `capacity` bytes of them, the least
/// recently used dropped first. An image larger than the whole cache is decoded, used and not
/// kept.
pub struct FrameCache {
    capacity: usize,
    state: Mutex<CacheState>,
    /// Signalled whenever a decode finishes (waiters for the same key wake up).
    decoded: Condvar,
    /// Jobs for the background decoder, started on the first prefetch.
    prefetcher: Mutex<Option<Sender<PrefetchJob>>>,
    /// The cache itself, for the background decoder (which must not keep it alive).
    this: Weak<FrameCache>,
}

struct PrefetchJob {
    key: u64,
    decode: Arc<DecodeImage>,
}

#[derive(Default)]
struct CacheState {
    entries: HashMap<u64, Entry>,
    /// Keys sent to the background decoder and not yet decoded.
    queued: HashSet<u64>,
    bytes: usize,
    stats: CacheStats,
    clock: u64,
}

enum Entry {
    /// Being decoded by some thread; others wait for it.
    Decoding,
    Ready {
        image: Arc<RgbImage>,
        last_use: u64,
    },
}

/// What a cache has done so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Requests answered from the cache (including those that waited for a background decode).
    pub hits: u64,
    /// Requests that decoded on the caller's thread.
    pub misses: u64,
    /// Images decoded by the background decoder.
    pub prefetched: u64,
    /// Most bytes held at once.
    pub peak_bytes: usize,
}

impl FrameCache {
    /// An empty cache that holds at most `capacity` bytes of decoded images.
    pub fn new(capacity: usize) -> Arc<Self> {
        Arc::new_cyclic(|this| Self {
            capacity,
            state: Mutex::new(CacheState::default()),
            decoded: Condvar::new(),
            prefetcher: Mutex::new(None),
            this: this.clone(),
        })
    }

    /// The most bytes of decoded images it holds.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Bytes of decoded images held now.
    pub fn resident_bytes(&self) -> usize {
        self.lock().bytes
    }

    /// Hits, misses, background decodes and the peak of held bytes.
    pub fn stats(&self) -> CacheStats {
        self.lock().stats
    }

    fn lock(&self) -> MutexGuard<'_, CacheState> {
        // A panic while holding the lock leaves consistent state (every update is one step).
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The image under `key`, decoding it with `decode` unless held or being decoded.
    fn get(&self, key: u64, decode: &DecodeImage) -> Result<Arc<RgbImage>, DataError> {
        self.fetch(key, decode, false)
    }

    fn fetch(
        &self,
        key: u64,
        decode: &DecodeImage,
        background: bool,
    ) -> Result<Arc<RgbImage>, DataError> {
        let mut state = self.lock();
        if background {
            // Taken off the queue whatever happens next, so a later prefetch can queue it again.
            state.queued.remove(&key);
        }
        loop {
            state.clock += 1;
            let now = state.clock;
            match state.entries.get_mut(&key) {
                Some(Entry::Ready { image, last_use }) => {
                    *last_use = now;
                    let image = image.clone();
                    if !background {
                        state.stats.hits += 1;
                    }
                    return Ok(image);
                }
                Some(Entry::Decoding) => {
                    state = self.decoded.wait(state).unwrap_or_else(|e| e.into_inner());
                }
                None => break,
            }
        }
        state.entries.insert(key, Entry::Decoding);
        if background {
            state.stats.prefetched += 1;
        } else {
            state.stats.misses += 1;
        }
        drop(state);

        // Waiters must not wait forever if `decode` panics: the guard withdraws the entry.
        let pending = Pending { cache: self, key };
        let decoded = decode().map(Arc::new);
        std::mem::forget(pending);

        let mut state = self.lock();
        state.entries.remove(&key);
        if let Ok(image) = &decoded {
            self.insert(&mut state, key, image.clone());
        }
        drop(state);
        self.decoded.notify_all();
        decoded
    }

    /// Holds `image` under `key`, dropping the least recently used images to make room; an
    /// image larger than the cache is not held.
    fn insert(&self, state: &mut CacheState, key: u64, image: Arc<RgbImage>) {
        let size = image.as_raw().len();
        if size > self.capacity {
            return;
        }
        while state.bytes + size > self.capacity {
            let oldest = state
                .entries
                .iter()
                .filter_map(|(&k, entry)| match entry {
                    Entry::Ready { last_use, .. } => Some((*last_use, k)),
                    Entry::Decoding => None,
                })
                .min();
            let Some((_, oldest)) = oldest else { break };
            if let Some(Entry::Ready { image, .. }) = state.entries.remove(&oldest) {
                state.bytes -= image.as_raw().len();
            }
        }
        state.clock += 1;
        let last_use = state.clock;
        state.entries.insert(key, Entry::Ready { image, last_use });
        state.bytes += size;
        state.stats.peak_bytes = state.stats.peak_bytes.max(state.bytes);
    }

    /// Queues `key` for the background decoder unless it is held, being decoded or queued.
    fn prefetch(&self, key: u64, decode: &Arc<DecodeImage>) {
        {
            let mut state = self.lock();
            if state.entries.contains_key(&key) || !state.queued.insert(key) {
                return;
            }
        }
        let mut prefetcher = self.prefetcher.lock().unwrap_or_else(|e| e.into_inner());
        let sender = prefetcher.get_or_insert_with(|| self.start_decoder());
        let job = PrefetchJob {
            key,
            decode: decode.clone(),
        };
        if sender.send(job).is_err() {
            // The decoder thread is gone (it panicked): decode on demand from now on.
            self.lock().queued.remove(&key);
        }
    }

    /// Starts the background decoder: one thread that decodes queued images into the cache
    /// and ends when the cache is dropped.
    fn start_decoder(&self) -> Sender<PrefetchJob> {
        let (sender, jobs) = channel::<PrefetchJob>();
        let cache = self.this.clone();
        let spawned = std::thread::Builder::new()
            .name("tadgs-prefetch".into())
            .spawn(move || {
                for job in jobs {
                    let Some(cache) = cache.upgrade() else { break };
                    // An error here is reported again by the request that needs the image.
                    let _ = cache.fetch(job.key, &*job.decode, true);
                }
            });
        if let Err(e) = spawned {
            tracing::warn!(
                "cannot start the background image decoder ({e}); images are read on demand"
            );
        }
        sender
    }
}

/// An image being decoded; dropped only by a panic in the decoder, when it withdraws the
/// entry and wakes the waiters (who then decode it themselves).
struct Pending<'a> {
    cache: &'a FrameCache,
    key: u64,
}

impl Drop for Pending<'_> {
    fn drop(&mut self) {
        self.cache.lock().entries.remove(&self.key);
        self.cache.decoded.notify_all();
    }
}

impl fmt::Debug for FrameCache {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("FrameCache")
            .field("capacity", &self.capacity)
            .field("resident_bytes", &self.resident_bytes())
            .finish()
    }
}

/// Bytes a whole dataset's decoded images may take before it is streamed by default: the
/// images then leave at least half the available memory to the model and its buffers.
pub fn default_in_memory_limit(available: Option<u64>) -> u64 {
    available.map_or(u64::MAX, |a| a / 2)
}

/// The cache size used when `data.cache_mb` is not given and the images are too large to
/// load: a quarter of the available memory, at least 256 MB.
pub fn default_cache_bytes(available: Option<u64>) -> u64 {
    available.map_or(1 << 30, |a| (a / 4).max(256 << 20))
}

/// How a reader holds the images of a dataset of `total_bytes` decoded bytes: `None` to load
/// them all, or the cache to stream them through. `cache_mb` is the `data.cache_mb` setting:
/// given, always stream through a cache of that many megabytes; not given, load everything
/// unless it would take more than half the available memory.
pub fn plan(cache_mb: Option<f64>, total_bytes: u64) -> Option<Arc<FrameCache>> {
    let available = crate::budget::available_memory();
    let capacity = match cache_mb {
        Some(mb) => (mb * 1e6) as u64,
        None if total_bytes <= default_in_memory_limit(available) => return None,
        None => {
            let capacity = default_cache_bytes(available);
            tracing::info!(
                "the decoded images take {:.1} GB, more than half the available memory: \
                 streaming them from disk through a {:.1} GB cache (set data.cache_mb to choose)",
                total_bytes as f64 / 1e9,
                capacity as f64 / 1e9
            );
            capacity
        }
    };
    Some(FrameCache::new(capacity as usize))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;

    fn counted(
        counter: &Arc<AtomicUsize>,
        value: u8,
    ) -> impl Fn() -> Result<RgbImage, DataError> + Send + Sync + 'static + use<> {
        let counter = counter.clone();
        move || {
            counter.fetch_add(1, Ordering::SeqCst);
            Ok(RgbImage::from_pixel(10, 10, image::Rgb([value; 3])))
        }
    }

    #[test]
    fn cache_keeps_at_most_its_capacity_dropping_the_least_recently_used() {
        // Each image is 300 bytes; room for two.
        let cache = FrameCache::new(650);
        let decodes = Arc::new(AtomicUsize::new(0));
        let views: Vec<ViewImage> = (0..4)
            .map(|i| {
                ViewImage::streamed(Path::new("v.png"), (10, 10), &cache, counted(&decodes, i))
            })
            .collect();
        for view in &views[..2] {
            view.pixels().unwrap();
        }
        views[0].pixels().unwrap(); // 0 is now more recent than 1
        views[2].pixels().unwrap(); // evicts 1
        assert_eq!(cache.resident_bytes(), 600);
        assert_eq!(decodes.load(Ordering::SeqCst), 3);
        assert_eq!(views[0].pixels().unwrap().get_pixel(0, 0).0, [0; 3]);
        assert_eq!(decodes.load(Ordering::SeqCst), 3, "0 stayed cached");
        views[1].pixels().unwrap();
        assert_eq!(decodes.load(Ordering::SeqCst), 4, "1 had been evicted");
        for view in &views {
            view.pixels().unwrap();
        }
        let stats = cache.stats();
        assert!(stats.peak_bytes <= 650, "{stats:?}");
        assert_eq!(stats.hits + stats.misses, 10);
    }

    #[test]
    fn image_larger_than_the_cache_is_decoded_but_not_kept() {
        let cache = FrameCache::new(100);
        let decodes = Arc::new(AtomicUsize::new(0));
        let view = ViewImage::streamed(Path::new("v.png"), (10, 10), &cache, counted(&decodes, 7));
        assert_eq!(view.pixels().unwrap().get_pixel(9, 9).0, [7; 3]);
        view.pixels().unwrap();
        assert_eq!(decodes.load(Ordering::SeqCst), 2);
        assert_eq!(cache.resident_bytes(), 0);
    }

    #[test]
    fn prefetched_image_is_served_without_decoding_again() {
        let cache = FrameCache::new(10_000);
        let decodes = Arc::new(AtomicUsize::new(0));
        let view = ViewImage::streamed(Path::new("v.png"), (10, 10), &cache, counted(&decodes, 3));
        view.prefetch();
        view.prefetch(); // queued once
        let image = view.pixels().unwrap();
        assert_eq!(image.get_pixel(0, 0).0, [3; 3]);
        assert_eq!(decodes.load(Ordering::SeqCst), 1);
        let stats = cache.stats();
        assert_eq!(stats.prefetched + stats.misses, 1, "{stats:?}");
    }

    #[test]
    fn image_evicted_after_a_prefetch_can_be_prefetched_again() {
        // Room for one image: each fetch evicts the other. Whichever of the prefetch and the
        // fetch decodes `a` first, the queue must end empty, or `a` could never be prefetched
        // again.
        let cache = FrameCache::new(300);
        let decodes = Arc::new(AtomicUsize::new(0));
        let a = ViewImage::streamed(Path::new("a.png"), (10, 10), &cache, counted(&decodes, 1));
        let b = ViewImage::streamed(Path::new("b.png"), (10, 10), &cache, counted(&decodes, 2));
        for _ in 0..20 {
            a.prefetch();
            a.pixels().unwrap();
            b.pixels().unwrap();
        }
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while !cache.lock().queued.is_empty() && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert!(cache.lock().queued.is_empty());
    }

    #[test]
    fn decoder_panic_does_not_leave_waiters_hanging() {
        let cache = FrameCache::new(10_000);
        let view = ViewImage::streamed(Path::new("p.png"), (10, 10), &cache, || {
            panic!("bad decoder")
        });
        let first = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| view.pixels()));
        assert!(first.is_err());
        assert!(
            cache.lock().entries.is_empty(),
            "the pending entry was withdrawn"
        );
    }

    #[test]
    fn decode_error_reaches_the_caller_and_is_not_cached() {
        let cache = FrameCache::new(10_000);
        let attempts = Arc::new(AtomicUsize::new(0));
        let counter = attempts.clone();
        let view = ViewImage::streamed(Path::new("v.png"), (10, 10), &cache, move || {
            counter.fetch_add(1, Ordering::SeqCst);
            Err(DataError::io(
                std::path::Path::new("gone.jpg"),
                std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
            ))
        });
        let error = view.pixels().unwrap_err().to_string();
        assert!(error.contains("gone.jpg"), "{error}");
        assert!(view.pixels().is_err());
        assert_eq!(attempts.load(Ordering::SeqCst), 2);
    }

    #[test]
    fn wrong_size_from_disk_is_an_error() {
        let cache = FrameCache::new(10_000);
        let decodes = Arc::new(AtomicUsize::new(0));
        let view = ViewImage::streamed(Path::new("v.png"), (12, 10), &cache, counted(&decodes, 0));
        let error = view.pixels().unwrap_err().to_string();
        assert!(error.contains("v.png") && error.contains("12"), "{error}");
    }

    #[test]
    fn mapped_streamed_image_is_transformed_after_decoding() {
        let cache = FrameCache::new(10_000);
        let decodes = Arc::new(AtomicUsize::new(0));
        let view =
            ViewImage::streamed(Path::new("v.png"), (10, 10), &cache, counted(&decodes, 200));
        let half = view.map((5, 5), |image| crate::io::image::box_downscale(image, 2));
        assert_eq!(half.dimensions(), (5, 5));
        assert_eq!(half.pixels().unwrap().get_pixel(4, 4).0, [200; 3]);
        assert!(half.cache().is_some());
    }
}
