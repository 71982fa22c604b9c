//! The admission budget: views are admitted by what they cost, not by how many there
//! are. Three limits, all fixed at start: the pixels rendered per frame over every view
//! (`max_pixels_per_frame`, the frame-time budget), the GPU memory of every view's
//! volumes and G-buffer together (`max_view_memory_mib`, [`viewer_memory_bytes`]), and
//! the largest storage buffer the adapter binds — the render loop batches all views of
//! one size into one set of per-viewer volumes, so N views of W×H must fit one binding
//! ([`largest_binding`]).
//! A hello or configure past either is refused with `over_budget`, naming the limit and
//! the largest frame of that layout that would fit now; a size the protocol accepts
//! therefore never fails later for want of memory.

use super::validate::{ProtocolError, SessionSpec, SpecLimits};
use crate::protocol::ErrorCode;
use crate::render::{
    largest_binding, micro_bytes_per_pixel, triangle_list_bytes_per_view, viewer_memory_bytes,
    Settings,
};
use std::collections::BTreeMap;

/// The limits views are admitted against.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Budget {
    /// Renderer settings (they size the per-viewer volumes).
    pub(crate) settings: Settings,
    /// The adapter's largest storage buffer binding, bytes.
    pub(crate) max_binding_bytes: u64,
    /// Pixels per frame over all views.
    pub(crate) max_pixels_per_frame: u64,
    /// GPU memory of all views' volumes and G-buffers, bytes.
    pub(crate) max_view_memory_bytes: u64,
    /// The scene's smoke particle capacity (0 without emitters): every view holds a proxy
    /// list of that many and a smoke layer.
    pub(crate) smoke_particles: u32,
    /// What the G-buffer's triangle culling holds per view at most
    /// ([`triangle_list_bytes_per_view`]; 0 with it off).
    pub(crate) triangle_lists_per_view: u64,
    /// What the G-buffer's small triangles hold per pixel of every view
    /// ([`micro_bytes_per_pixel`]; 0 where `micro_raster` does not apply).
    pub(crate) micro_bytes_per_pixel: u64,
}

/// What is rendered now: views per view size.
#[derive(Debug, Default, Clone)]
pub(crate) struct Usage {
    views_by_size: BTreeMap<(u32, u32), u64>,
}

impl Usage {
    pub(crate) fn add(&mut self, spec: &SessionSpec) {
        *self
            .views_by_size
            .entry((spec.view_width, spec.view_height))
            .or_default() += spec.views as u64;
    }

    fn pixels(&self) -> u64 {
        self.views_by_size
            .iter()
            .map(|(&(w, h), &n)| n * w as u64 * h as u64)
            .sum()
    }
}

fn mib(bytes: u64) -> f64 {
    bytes as f64 / 1048576.0
}

impl Budget {
    /// This budget with the G-buffer's per-view memory for a scene of `static_triangles`
    /// (triangles, not indices: both structures are sized from the one count).
    pub(crate) fn with_triangles(self, static_triangles: u64) -> Budget {
        Budget {
            triangle_lists_per_view: triangle_list_bytes_per_view(&self.settings, static_triangles),
            micro_bytes_per_pixel: micro_bytes_per_pixel(&self.settings, static_triangles),
            ..self
        }
    }

    /// GPU memory the views of `views_by_size` hold: volumes, G-buffers and the
    /// G-buffer's culling structures.
    fn memory_of(&self, views_by_size: &BTreeMap<(u32, u32), u64>) -> u64 {
        views_by_size
            .iter()
            .map(|(&(w, h), &n)| {
                viewer_memory_bytes(&self.settings, n as usize, w, h, self.smoke_particles)
                    + n * self.triangle_lists_per_view
                    + n * u64::from(w) * u64::from(h) * self.micro_bytes_per_pixel
            })
            .sum()
    }

    /// Why `spec` does not fit next to `used`, if it does not.
    fn exceeds(&self, used: &Usage, spec: &SessionSpec) -> Option<String> {
        let (w, h) = (spec.view_width, spec.view_height);
        let asked = spec.views as u64 * w as u64 * h as u64;
        let in_use = used.pixels();
        if in_use + asked > self.max_pixels_per_frame {
            return Some(format!(
                "{} view(s) of {w}×{h} need {asked} pixels per frame and {in_use} of the server's budget of {} are in use",
                spec.views, self.max_pixels_per_frame
            ));
        }
        let mut sizes = used.views_by_size.clone();
        *sizes.entry((w, h)).or_default() += spec.views as u64;
        let memory = self.memory_of(&sizes);
        if memory > self.max_view_memory_bytes {
            return Some(format!(
                "with {} view(s) of {w}×{h} the views would hold {:.1} MiB of GPU memory and the server's budget is {:.1} MiB",
                spec.views,
                mib(memory),
                mib(self.max_view_memory_bytes)
            ));
        }
        let count = sizes[&(w, h)];
        let (label, bytes) = largest_binding(&self.settings, count as usize, w, h);
        (bytes > self.max_binding_bytes).then(|| {
            format!(
                "{count} view(s) of {w}×{h} in one batch need a {:.1} MiB {label} buffer but the GPU binds at most {:.1} MiB per buffer",
                mib(bytes),
                mib(self.max_binding_bytes)
            )
        })
    }

    /// `Ok` if `spec` fits next to `used`; else an `over_budget` error naming the limit
    /// and the largest frame of the same layout and aspect that fits now.
    pub(crate) fn admit(
        &self,
        used: &Usage,
        spec: &SessionSpec,
        limits: &SpecLimits,
    ) -> Result<(), ProtocolError> {
        let Some(why) = self.exceeds(used, spec) else {
            return Ok(());
        };
        let shrunk = |fw: u32| {
            let fh = ((fw as u64 * spec.height as u64) / spec.width as u64) as u32;
            SessionSpec::validate(
                fw,
                fh,
                spec.layout,
                Some(spec.views),
                Some(spec.quality),
                Some(spec.eye_distance_m),
                limits,
            )
            .ok()
            .filter(|s| self.exceeds(used, s).is_none())
        };
        // Binary search on the frame width: cost grows with size.
        let (mut lo, mut hi, mut best) = (1u32, spec.width.saturating_sub(1), None);
        while lo <= hi {
            let mid = lo + (hi - lo) / 2;
            match shrunk(mid) {
                Some(s) => {
                    best = Some(s);
                    lo = mid + 1;
                }
                None => hi = mid - 1,
            }
        }
        let offer = match best {
            Some(s) => format!(
                "; the largest frame of this layout that fits now is {}×{}",
                s.width, s.height
            ),
            None => "; no frame of this layout fits now, try again later".into(),
        };
        Err(ProtocolError::new(
            ErrorCode::OverBudget,
            format!("{why}{offer}"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::Layout;
    use crate::server::validate::TEST_LIMITS as LIMITS;

    fn mono(w: u32, h: u32) -> SessionSpec {
        SessionSpec::validate(w, h, Layout::Mono, None, None, None, &LIMITS).unwrap()
    }

    #[test]
    fn the_fifth_1080p_view_is_refused_with_the_limit_and_an_offer() {
        let budget = Budget {
            settings: Settings::default(),
            max_binding_bytes: 128 << 20,
            max_pixels_per_frame: u64::MAX,
            max_view_memory_bytes: u64::MAX,
            smoke_particles: 0,
            triangle_lists_per_view: 0,
            micro_bytes_per_pixel: 0,
        };
        // The numbers: five 1920×1080 views need 158.2 MiB of froxels.
        let (label, bytes) = largest_binding(&budget.settings, 5, 1920, 1080);
        assert_eq!(
            (label, format!("{:.1}", mib(bytes))),
            ("froxels", "158.2".into())
        );
        let mut used = Usage::default();
        for _ in 0..4 {
            budget.admit(&used, &mono(1920, 1080), &LIMITS).unwrap();
            used.add(&mono(1920, 1080));
        }
        let e = budget.admit(&used, &mono(1920, 1080), &LIMITS).unwrap_err();
        assert_eq!(e.code, ErrorCode::OverBudget);
        assert!(
            e.message.contains("158.2 MiB") && e.message.contains("128.0 MiB"),
            "{}",
            e.message
        );
        // The offer is a size that is admitted.
        let offer = e.message.rsplit(" is ").next().unwrap();
        let (w, h) = offer.split_once('×').unwrap();
        let s = mono(w.parse().unwrap(), h.parse().unwrap());
        budget.admit(&used, &s, &LIMITS).unwrap();
        assert!(s.width < 1920 && s.width > 1000, "{offer}");
        // Another size is its own batch: it fits.
        budget.admit(&used, &mono(320, 180), &LIMITS).unwrap();
    }

    #[test]
    fn pixels_per_frame_are_a_budget() {
        let budget = Budget {
            settings: Settings::default(),
            max_binding_bytes: u64::MAX,
            max_pixels_per_frame: 1280 * 720 * 3 / 2,
            max_view_memory_bytes: u64::MAX,
            smoke_particles: 0,
            triangle_lists_per_view: 0,
            micro_bytes_per_pixel: 0,
        };
        let mut used = Usage::default();
        used.add(&mono(1280, 720));
        let e = budget.admit(&used, &mono(1280, 720), &LIMITS).unwrap_err();
        assert!(e.message.contains("pixels per frame"), "{}", e.message);
        budget.admit(&used, &mono(320, 180), &LIMITS).unwrap();
    }

    #[test]
    fn the_g_buffers_structures_are_sized_from_one_triangle_count() {
        let base = Budget {
            settings: Settings::default(),
            max_binding_bytes: u64::MAX,
            max_pixels_per_frame: u64::MAX,
            max_view_memory_bytes: u64::MAX,
            smoke_particles: 0,
            triangle_lists_per_view: 0,
            micro_bytes_per_pixel: 0,
        };
        // 100,000 triangles: past MICRO_MIN_TRIANGLES, but not 3 times past it (a count of
        // indices divided by 3 twice planned no small-triangle buffer here).
        let b = base.with_triangles(100_000);
        assert_eq!(b.micro_bytes_per_pixel, 8);
        // 12 B a triangle for the view's index list, and the cluster records on top.
        assert!(
            (1_200_000..1_300_000).contains(&b.triangle_lists_per_view),
            "{}",
            b.triangle_lists_per_view
        );
        // A small scene: lists, no small-triangle buffer; culling off: neither.
        let small = base.with_triangles(1_000);
        assert_eq!(small.micro_bytes_per_pixel, 0);
        assert!(small.triangle_lists_per_view >= 12_000);
        let mut off = base;
        off.settings.triangle_cull = false;
        let off = off.with_triangles(100_000);
        assert_eq!(
            (off.triangle_lists_per_view, off.micro_bytes_per_pixel),
            (0, 0)
        );
        // The view memory a 1280×720 view is admitted against counts both.
        let mut used = Usage::default();
        used.add(&mono(1280, 720));
        let with = b.memory_of(&used.views_by_size);
        let without = base.memory_of(&used.views_by_size);
        assert_eq!(with - without, b.triangle_lists_per_view + 1280 * 720 * 8);
    }

    #[test]
    fn views_memory_is_a_budget() {
        // One 1280×720 view: froxels and integrated 2 × 160×90×128×8 B, culling
        // columns, output and a 20 B/px G-buffer (the frustum is a one-slice stand-in
        // with `map_edges`): about 49 MiB.
        let one = viewer_memory_bytes(&Settings::default(), 1, 1280, 720, 0);
        assert!((46 << 20..53 << 20).contains(&one), "{one}");
        // Views of one size stack (the 16-byte history stub is one per batch).
        let three = viewer_memory_bytes(&Settings::default(), 3, 1280, 720, 0);
        assert!(3 * one - three <= 32, "{three} vs 3 × {one}");
        // A smoke scene adds each view's proxy list (64 B a particle) and f16 RGBA layer.
        let smoky = viewer_memory_bytes(&Settings::default(), 1, 1280, 720, 300);
        assert_eq!(smoky - one, 300 * 64 + 1280 * 720 * 8);
        let budget = Budget {
            settings: Settings::default(),
            max_binding_bytes: u64::MAX,
            max_pixels_per_frame: u64::MAX,
            max_view_memory_bytes: one * 5 / 2,
            smoke_particles: 0,
            triangle_lists_per_view: 0,
            micro_bytes_per_pixel: 0,
        };
        let mut used = Usage::default();
        used.add(&mono(1280, 720));
        used.add(&mono(1280, 720));
        let e = budget.admit(&used, &mono(1280, 720), &LIMITS).unwrap_err();
        assert_eq!(e.code, ErrorCode::OverBudget);
        assert!(e.message.contains("MiB of GPU memory"), "{}", e.message);
        // What is left fits a smaller view, and the offer is admitted.
        budget.admit(&used, &mono(320, 180), &LIMITS).unwrap();
        let offer = e.message.rsplit(" is ").next().unwrap();
        let (ow, oh) = offer.split_once('×').unwrap();
        budget
            .admit(
                &used,
                &mono(ow.parse().unwrap(), oh.parse().unwrap()),
                &LIMITS,
            )
            .unwrap();
    }
}
