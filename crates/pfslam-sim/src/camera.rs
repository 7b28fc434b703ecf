//! The simulator's cameras: a [`World`] as the car's stereo rig (raw Bayer pairs and their
//! exact disparity) and the humanoid's RGB-D camera see it, by ray casting against its
//! textured ground and obstacles.

use super::raycast::{HitKind, RayCaster};
use super::world::World;
use nalgebra::Vector3;
use pfslam::geometry::{Pose2, Rigid3};
use pfslam::sensors::StereoCalibration;
use pfslam_stereo::StereoError;
use pfslam_stereo::image::{BayerPattern, GrayImage, RgbImage};
use pfslam_stereo::rectify::{PinholeIntrinsics, RectifiedGeometry};
use pfslam_stereo::render::{grain, hash01, render_pair, true_disparity};
use rayon::prelude::*;

/// A simulator world as the car's cameras see it: its ground texture (times [`grain`]) and
/// its obstacles (a muted colour per obstacle times grain), sky beyond `max_range_m`.
#[derive(Debug, Clone)]
pub struct WorldScene<'a> {
    world: &'a World,
    caster: RayCaster,
    /// Colour of rays that hit nothing.
    pub sky: [f64; 3],
    /// Rays end here (m).
    pub max_range_m: f64,
}

impl<'a> WorldScene<'a> {
    /// Prepares the world for ray casting.
    pub fn new(world: &'a World, max_range_m: f64) -> Self {
        WorldScene {
            world,
            caster: RayCaster::new(world, 2.0, 5.0),
            sky: [175.0, 195.0, 220.0],
            max_range_m,
        }
    }

    /// The true ground colour at a world point (what texture mapping should recover).
    pub fn ground_rgb(&self, x_m: f64, y_m: f64) -> [f64; 3] {
        let g = grain(x_m, y_m);
        self.world
            .ground
            .rgb_at(x_m, y_m)
            .map(|c| (c as f64 * g).min(255.0))
    }

    /// Colour seen along a world ray.
    pub fn shade(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> [f64; 3] {
        match self
            .caster
            .cast([o.x, o.y, o.z], [d.x, d.y, d.z], self.max_range_m)
        {
            Some(hit) => {
                let p = o + d * hit.range_m;
                match hit.kind {
                    HitKind::Ground => self.ground_rgb(p.x, p.y),
                    HitKind::Obstacle(i) => {
                        let base = [
                            90.0 + 100.0 * hash01(i as i64, 0, 7),
                            90.0 + 100.0 * hash01(i as i64, 1, 7),
                            90.0 + 100.0 * hash01(i as i64, 2, 7),
                        ];
                        let g = grain(p.x + 1.3 * p.z, p.y + 0.7 * p.z);
                        base.map(|c| (c * g).min(255.0))
                    }
                }
            }
            None => self.sky,
        }
    }

    /// Distance (m) to the first surface along a world ray.
    pub fn range(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<f64> {
        self.caster
            .cast([o.x, o.y, o.z], [d.x, d.y, d.z], self.max_range_m)
            .map(|h| h.range_m)
    }

    /// The raw Bayer pair of the car's rig at `world_from_body`.
    pub fn render_pair(
        &self,
        calib: &StereoCalibration,
        world_from_body: &Pose2,
        supersample: usize,
        pattern: BayerPattern,
    ) -> Result<(GrayImage, GrayImage), StereoError> {
        let shade = |o: &Vector3<f64>, d: &Vector3<f64>| self.shade(o, d);
        render_pair(calib, world_from_body, &shade, supersample, pattern)
    }

    /// The exact disparity of the left rectified image at `world_from_body`.
    pub fn true_disparity(
        &self,
        geometry: &RectifiedGeometry,
        world_from_body: &Pose2,
    ) -> Vec<f32> {
        let range = |o: &Vector3<f64>, d: &Vector3<f64>| self.range(o, d);
        true_disparity(geometry, world_from_body, &range)
    }
}

impl WorldScene<'_> {
    /// Renders a registered RGB-D frame (the humanoid's Kinect) of the pinhole camera
    /// `world_from_camera` (x right, y down, z forward): depth along the optical axis (m, 0
    /// where nothing is hit) and colour, one ray per pixel.
    pub fn render_rgbd(
        &self,
        intrinsics: &PinholeIntrinsics,
        world_from_camera: &Rigid3,
    ) -> (Vec<f32>, RgbImage) {
        let (w, h) = (intrinsics.width, intrinsics.height);
        let mut depth = vec![0f32; w * h];
        let mut colour = RgbImage::new(w, h);
        let o = world_from_camera.translation;
        depth
            .par_chunks_mut(w.max(1))
            .zip(colour.data.par_chunks_mut(3 * w.max(1)))
            .enumerate()
            .for_each(|(v, (drow, crow))| {
                for u in 0..w {
                    let ray = intrinsics.ray(u as f64, v as f64);
                    let norm = ray.norm();
                    let dir = world_from_camera.rotation * (ray / norm);
                    let rgb = self.shade(&o, &dir);
                    if let Some(r) = self.range(&o, &dir) {
                        drow[u] = (r / norm) as f32;
                    }
                    for (c, x) in crow[3 * u..3 * u + 3].iter_mut().zip(rgb) {
                        *c = x.round().clamp(0.0, 255.0) as u8;
                    }
                }
            });
        (depth, colour)
    }
}
