//! The downward polarization camera (an IMX250MZR-class sensor behind a dome port): exposes one
//! frame on each rising edge of its trigger input (GPIO 0 of the bridge, driven by the head's
//! `HeadSuite::with_camera_trigger`), numbers its frames from 0 as a real camera's frame counter
//! does, and hands each frame to the host side (`crate::map_loop`), which stamps it with the
//! head's time from the matching `Uplink::Trigger` message, not from this model.
//!
//! The image itself comes from a caller-supplied exposure (`FnMut(t_us) -> CameraImage`: in a
//! dive the seafloor rendered at the truth pose of that instant, reduced to its feature vector).
//!
//! Faults, as a field camera shows them: a blackout window (frames keep coming, dark: no
//! features), dropped frames (never delivered: a gap in the counter), duplicated frames (the
//! same frame delivered twice) and frames delivered out of order (held back behind the next).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What one exposure sees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraImage {
    /// The image's feature vector (`None`: nothing usable, e.g. dark).
    pub features: Option<[f64; subnav_topo::polar_image::N_FEATURES]>,
    /// Truth at the exposure (north, east), for scoring only.
    pub truth_ne_m: [f64; 2],
}

/// A frame as the camera hands it over.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraCapture {
    /// The camera's own frame counter.
    pub frame: u32,
    /// When the simulator exposed it (µs since boot): schedules the host's processing; the
    /// frame's time of validity comes from the head's trigger message.
    pub exposed_us: u64,
    pub image: CameraImage,
}

/// Camera faults.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CameraFaults {
    /// Frames exposed in this window (µs since boot) are dark.
    pub blackout_us: Option<(u64, u64)>,
    pub drop_probability: f64,
    pub duplicate_probability: f64,
    pub reorder_probability: f64,
}

pub type Exposure = Box<dyn FnMut(u64) -> CameraImage + Send>;
pub type Delivery = Box<dyn FnMut(CameraCapture) + Send>;

pub struct CameraModel {
    level: bool,
    next_frame: u32,
    expose: Exposure,
    deliver: Delivery,
    held: Option<CameraCapture>,
    rng: ChaCha8Rng,
    pub faults: CameraFaults,
    /// Rising edges seen (frames exposed).
    pub exposures: u64,
}

impl CameraModel {
    pub fn new(seed: u64, expose: Exposure, deliver: Delivery) -> Self {
        Self {
            level: false,
            next_frame: 0,
            expose,
            deliver,
            held: None,
            rng: ChaCha8Rng::seed_from_u64(seed),
            faults: CameraFaults::default(),
            exposures: 0,
        }
    }

    fn expose_frame(&mut self, t_us: u64) {
        let frame = self.next_frame;
        self.next_frame = self.next_frame.wrapping_add(1);
        self.exposures += 1;
        let mut image = (self.expose)(t_us);
        if self.faults.blackout_us.is_some_and(|(a, b)| (a..b).contains(&t_us)) {
            image.features = None;
        }
        let f = self.faults;
        // One draw per fault kind per frame, in a fixed order (the same faults for a seed).
        let (drop, dup, reorder) = (
            self.rng.random::<f64>() < f.drop_probability,
            self.rng.random::<f64>() < f.duplicate_probability,
            self.rng.random::<f64>() < f.reorder_probability,
        );
        if drop {
            return;
        }
        let cap = CameraCapture { frame, exposed_us: t_us, image };
        if reorder && self.held.is_none() {
            self.held = Some(cap);
            return;
        }
        (self.deliver)(cap);
        if dup {
            (self.deliver)(cap);
        }
        if let Some(h) = self.held.take() {
            (self.deliver)(h);
        }
    }
}

impl super::GpioChip for CameraModel {
    fn set(&mut self, t_us: u64, high: bool) {
        if high && !self.level {
            self.expose_frame(t_us);
        }
        self.level = high;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chips::GpioChip;
    use std::sync::{Arc, Mutex};

    fn model(out: Arc<Mutex<Vec<(u32, bool)>>>) -> CameraModel {
        let expose: Exposure = Box::new(|t_us| CameraImage { features: Some([t_us as f64; 20]), truth_ne_m: [0.0; 2] });
        let deliver: Delivery =
            Box::new(move |c| out.lock().unwrap_or_else(|e| e.into_inner()).push((c.frame, c.image.features.is_some())));
        CameraModel::new(3, expose, deliver)
    }

    #[test]
    fn one_frame_per_rising_edge_numbered_from_zero() {
        let out = Arc::new(Mutex::new(Vec::new()));
        let mut cam = model(out.clone());
        for (t, level) in [(0, true), (1, true), (2, false), (3, false), (4, true), (5, false)] {
            cam.set(t, level);
        }
        assert_eq!(*out.lock().unwrap(), vec![(0, true), (1, true)]);
    }

    #[test]
    fn faults_blackout_drop_duplicate_reorder() {
        let out = Arc::new(Mutex::new(Vec::new()));
        let mut cam = model(out.clone());
        cam.faults = CameraFaults {
            blackout_us: Some((10_000, 20_000)),
            drop_probability: 0.1,
            duplicate_probability: 0.1,
            reorder_probability: 0.1,
        };
        for k in 0..400u64 {
            cam.set(k * 1000, true);
            cam.set(k * 1000 + 1, false);
        }
        let got = out.lock().unwrap().clone();
        assert!(got.iter().filter(|(f, _)| (10..20).contains(f)).all(|(_, img)| !img), "blackout frames are dark");
        let frames: Vec<u32> = got.iter().map(|g| g.0).collect();
        let dups = frames.windows(2).filter(|w| w[0] == w[1]).count();
        let back = frames.windows(2).filter(|w| w[1] < w[0]).count();
        let mut uniq = frames.clone();
        uniq.sort();
        uniq.dedup();
        let missing = 400 - uniq.len();
        assert!(dups > 10 && back > 10 && missing > 10, "dups {dups} reordered {back} missing {missing}");
    }
}
