use super::truth::{camera_frames, ImageTruth};
use super::*;
use crate::sim::world::Primitive;
use crate::sim::{simulate, Scenario, SimConfig, SimOutput};

fn sim(scenario: Scenario, seed: u64, duration_s: f64) -> SimOutput {
    let mut cfg = SimConfig::new(scenario, seed, duration_s);
    cfg.lidar = Some(crate::sim::LidarKind::None);
    simulate(&cfg, &|_, _, _| {}).unwrap()
}

/// Camera at `o` looking along world +x (image x = -y, image y = -z).
fn view_along_x(o: Vec3) -> View {
    View {
        o_w: o,
        r_wc: Mat3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0),
    }
}

fn wall(x: f64) -> Primitive {
    Primitive {
        shape: Shape::Box {
            min: Vec3::new(x, -60.0, 0.0),
            max: Vec3::new(x + 1.0, 60.0, 100.0),
        },
        material: Material::Building,
    }
}

/// Number of Shi-Tomasi corners (see [`shi_tomasi_corners`]).
fn shi_tomasi_count(px: &[u8], w: usize, h: usize, min_eig: f64) -> usize {
    shi_tomasi_corners(px, w, h, min_eig).len()
}

/// Shi-Tomasi corners: local maxima (11x11) of the minimum eigenvalue of the 5x5 structure
/// tensor of central-difference gradients, above `min_eig` (grey levels^2).
fn shi_tomasi_corners(px: &[u8], w: usize, h: usize, min_eig: f64) -> Vec<(usize, usize)> {
    let g = |x: usize, y: usize| f64::from(px[y * w + x]);
    let mut e = vec![0.0; w * h];
    let mut grad = vec![(0.0, 0.0); w * h];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            grad[y * w + x] = (
                0.5 * (g(x + 1, y) - g(x - 1, y)),
                0.5 * (g(x, y + 1) - g(x, y - 1)),
            );
        }
    }
    for y in 3..h - 3 {
        for x in 3..w - 3 {
            let (mut a, mut b, mut c) = (0.0, 0.0, 0.0);
            for yy in y - 2..=y + 2 {
                for xx in x - 2..=x + 2 {
                    let (gx, gy) = grad[yy * w + xx];
                    a += gx * gx;
                    b += gx * gy;
                    c += gy * gy;
                }
            }
            let (a, b, c) = (a / 25.0, b / 25.0, c / 25.0);
            e[y * w + x] = 0.5 * (a + c) - (0.25 * (a - c) * (a - c) + b * b).sqrt();
        }
    }
    let mut n = Vec::new();
    for y in 8..h - 8 {
        for x in 8..w - 8 {
            let v = e[y * w + x];
            if v < min_eig {
                continue;
            }
            let mut best = true;
            'nb: for yy in y - 5..=y + 5 {
                for xx in x - 5..=x + 5 {
                    let o = e[yy * w + xx];
                    if o > v || (o == v && (yy, xx) < (y, x)) {
                        best = false;
                        break 'nb;
                    }
                }
            }
            if best {
                n.push((x, y));
            }
        }
    }
    n
}

/// Centroid of a small disc painted on a fronto-parallel wall lands where `camera::project`
/// puts the disc's centre, over the whole (strongly distorted) EuRoC image.
#[test]
fn rendered_marker_lands_on_the_projection() {
    let world = World::new(vec![wall(10.0)], [-70.0, -70.0, 70.0, 70.0], 10.0);
    let cam = PinholeCamera::EUROC_CAM0;
    let o = Vec3::new(0.0, 0.0, 50.0);
    let view = view_along_x(o);
    let radius = 0.1;
    let mut worst: f64 = 0.0;
    for (y0, z0) in [
        (0.0, 50.0),
        (5.0, 53.0),
        (-6.5, 46.0),
        (7.0, 46.0),
        (-7.0, 54.5),
        (2.0, 51.0),
    ] {
        let r = Renderer::new(&world, cam, &Extrinsic::identity())
            .with_lighting(1.0, 0.0)
            .with_albedo(Box::new(move |_, _, c: &Chart| match *c {
                Chart::Plane { st, fp, .. } => {
                    let d = ((st[0] - y0).powi(2) + (st[1] - z0).powi(2)).sqrt();
                    let f = 0.5 * (fp[0] + fp[1]);
                    (0.5 - (d - radius) / f).clamp(0.0, 1.0)
                }
                Chart::Solid { .. } => 0.0,
            }));
        let opts = RenderOptions {
            supersample: 2,
            ..RenderOptions::default()
        };
        let img = r.radiance(&view, &opts);
        let (w, _) = (cam.width as usize, cam.height as usize);
        let (mut s, mut su, mut sv) = (0.0, 0.0, 0.0);
        for (i, &l) in img.iter().enumerate() {
            let l = f64::from(l);
            s += l;
            su += l * (i % w) as f64;
            sv += l * (i / w) as f64;
        }
        let proj = |y: f64, z: f64| {
            let p_c = view.r_wc.transpose() * (Vec3::new(10.0, y, z) - o);
            crate::sim::camera::project(&cam, &p_c).unwrap()
        };
        // Exact centroid of the disc's (distorted) image: image-area weighted mean over the disc.
        let (mut a, mut cu, mut cv) = (0.0, 0.0, 0.0);
        let n = 160;
        let hs = 1e-5;
        for iy in 0..n {
            for iz in 0..n {
                let dy = radius * (2.0 * (iy as f64 + 0.5) / n as f64 - 1.0);
                let dz = radius * (2.0 * (iz as f64 + 0.5) / n as f64 - 1.0);
                if dy * dy + dz * dz > radius * radius {
                    continue;
                }
                let p = proj(y0 + dy, z0 + dz);
                let py = proj(y0 + dy + hs, z0 + dz);
                let pz = proj(y0 + dy, z0 + dz + hs);
                let jac = ((py[0] - p[0]) * (pz[1] - p[1]) - (py[1] - p[1]) * (pz[0] - p[0])).abs();
                a += jac;
                cu += jac * p[0];
                cv += jac * p[1];
            }
        }
        let exact = [cu / a, cv / a];
        let uv = proj(y0, z0);
        let err = ((su / s - exact[0]).powi(2) + (sv / s - exact[1]).powi(2)).sqrt();
        let bias = ((uv[0] - exact[0]).powi(2) + (uv[1] - exact[1]).powi(2)).sqrt();
        assert!(s > 20.0, "marker at {uv:?} not rendered ({s})");
        eprintln!("marker at {uv:?}: {err:.4} px from its exact image centroid (distortion bias {bias:.4} px)");
        worst = worst.max(err);
    }
    eprintln!("marker centroid vs project: worst {worst:.4} px");
    assert!(
        worst < 0.02,
        "marker centroid {worst} px from the projection"
    );
}

/// The renderer's depth map, lifted back to 3-D, projects onto its pixel, and agrees with an
/// independent ray cast through the world grid (the tile culling misses nothing).
#[test]
fn depth_map_agrees_with_projection_and_world_raycast() {
    let out = sim(Scenario::Handheld, 3, 8.0);
    let truth = ImageTruth::new(&out);
    let cam = *truth.renderer().camera();
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut checked = 0;
    for i in [10usize, 80, 150] {
        let v = *truth.view(i).unwrap();
        let depth = truth.depth_map(i).unwrap();
        for row in (0..h).step_by(7) {
            for col in (0..w).step_by(5) {
                let z = f64::from(depth[row * w + col]);
                let uv = [col as f64, row as f64];
                let cast = truth.surface_point(i, uv);
                let Some((p, _)) = cast else {
                    assert!(
                        z.is_nan(),
                        "({col}, {row}) depth {z} but the world ray cast hits nothing"
                    );
                    continue;
                };
                let p_c = v.r_wc.transpose() * (p - v.o_w);
                assert!(
                    (p_c.z - z).abs() < 1e-4 * z.max(1.0),
                    "({col}, {row}): depth {z} vs cast {}",
                    p_c.z
                );
                let back = crate::sim::camera::project(&cam, &p_c).unwrap();
                assert!((back[0] - uv[0]).abs() < 1e-6 && (back[1] - uv[1]).abs() < 1e-6);
                checked += 1;
            }
        }
    }
    assert!(checked > 10_000, "{checked}");
}

/// A pixel transferred to another frame and back returns to itself; a point hidden behind an
/// occluder, or out of view, in the other frame has no transfer.
#[test]
fn transfer_round_trips_and_respects_occlusion() {
    let occluder = Primitive {
        shape: Shape::Box {
            min: Vec3::new(9.5, 1.2, 0.0),
            max: Vec3::new(10.5, 1.8, 3.0),
        },
        material: Material::Pole,
    };
    let world = World::new(vec![wall(20.0), occluder], [-70.0, -70.0, 70.0, 70.0], 5.0);
    let cam = PinholeCamera::EUROC_CAM0;
    let views = vec![
        view_along_x(Vec3::new(0.0, 0.0, 1.5)),
        view_along_x(Vec3::new(0.0, 3.0, 1.5)),
    ];
    let truth = ImageTruth::with_views(&world, cam, vec![0, 50_000_000], views.clone());
    let pix = |j: usize, p: Vec3| {
        crate::sim::camera::project(&cam, &(views[j].r_wc.transpose() * (p - views[j].o_w)))
            .unwrap()
    };
    // Hidden from frame 0 by the occluder, visible from frame 1.
    let hidden = Vec3::new(20.0, 3.0, 1.5);
    assert!(truth.transfer(1, pix(1, hidden), 0).is_none());
    // Visible from both: the transfer is the projection, and it round-trips.
    let seen = Vec3::new(20.0, -3.0, 2.0);
    let uv1 = pix(1, seen);
    let uv0 = truth.transfer(1, uv1, 0).unwrap();
    let p0 = pix(0, seen);
    assert!((uv0[0] - p0[0]).abs() < 1e-6 && (uv0[1] - p0[1]).abs() < 1e-6);
    let back = truth.transfer(0, uv0, 1).unwrap();
    assert!((back[0] - uv1[0]).abs() < 1e-6 && (back[1] - uv1[1]).abs() < 1e-6);
    // A point on the occluder seen from frame 0 is out of view or visible in 1, never hidden.
    assert!(truth
        .surface_point(0, pix(0, Vec3::new(9.5, 1.5, 1.5)))
        .is_some());
    // Out of view in frame 1: far to the side.
    let side = Vec3::new(20.0, -25.0, 1.5);
    assert!(truth.transfer(0, pix(0, side), 1).is_none());

    // On a simulated sequence: round trips over many pixels and frame pairs.
    let out = sim(Scenario::Robot, 2, 6.0);
    let t = ImageTruth::new(&out);
    let (mut ok, mut none) = (0, 0);
    for (i, j) in [(20usize, 22usize), (50, 60), (100, 101)] {
        for row in (10..470).step_by(23) {
            for col in (10..740).step_by(17) {
                let uv = [col as f64 + 0.3, row as f64 - 0.2];
                match t.transfer(i, uv, j) {
                    Some(q) => {
                        let b = t.transfer(j, q, i).expect("visible both ways");
                        assert!(
                            (b[0] - uv[0]).abs() < 1e-5 && (b[1] - uv[1]).abs() < 1e-5,
                            "{uv:?} -> {q:?} -> {b:?}"
                        );
                        ok += 1;
                    }
                    None => none += 1,
                }
            }
        }
    }
    assert!(ok > 1500 && none > 10, "{ok} transferred, {none} not");
}

fn render_all(out: &SimOutput, opts: &RenderOptions, seed: u64, threads: usize) -> Vec<Vec<u8>> {
    let n = out.dataset.features.len();
    let frames = std::sync::Mutex::new(vec![Vec::new(); n]);
    sequence::render_sequence(out, opts, seed, threads, &|_, _, _| {}, &|k, _, px| {
        frames.lock().unwrap()[k] = px;
        Ok(())
    })
    .unwrap();
    frames.into_inner().unwrap()
}

/// Same seed, same pixels, whatever the thread count; the seed drives the noise.
#[test]
fn rendering_is_deterministic_and_thread_count_independent() {
    let out = sim(Scenario::Handheld, 4, 0.3);
    let opts = RenderOptions {
        noise_grey: 2.0,
        exposure_var: 0.2,
        motion_blur_s: 0.004,
        ..RenderOptions::default()
    };
    let a = render_all(&out, &opts, 4, 1);
    let b = render_all(&out, &opts, 4, 2);
    let c = render_all(&out, &opts, 5, 2);
    assert_eq!(a.len(), 7);
    assert!(a.iter().all(|f| f.len() == 752 * 480));
    assert!(a == b, "thread count changed the pixels");
    assert!(a != c, "the seed does not reach the noise");
    // Without noise the images do not depend on the seed at all (the world does).
    let quiet = RenderOptions::default();
    assert!(render_all(&out, &quiet, 4, 2) == render_all(&out, &quiet, 9, 1));
}

/// Rendered frames of every scenario have plenty of Shi-Tomasi corners; a flat wall has none.
#[test]
fn textures_have_corners() {
    let min_eig = 25.0;
    for (sc, seed) in [
        (Scenario::Robot, 1),
        (Scenario::Handheld, 2),
        (Scenario::Vehicle, 3),
    ] {
        let out = sim(sc, seed, 6.0);
        let frames = camera_frames(&out);
        let r = Renderer::new(
            &out.world,
            out.dataset.calib.camera,
            &out.dataset.calib.t_bc,
        );
        for k in [frames.len() / 2, frames.len() - 1] {
            let px = r.render_frame(
                &out.trajectory,
                frames[k].1,
                k as u64,
                seed,
                &RenderOptions::default(),
            );
            let n = shi_tomasi_count(&px, 752, 480, min_eig);
            eprintln!("{} frame {k}: {n} corners", sc.name());
            assert!(n >= 150, "{} frame {k}: only {n} corners", sc.name());
        }
    }
    let world = World::new(vec![wall(10.0)], [-70.0, -70.0, 70.0, 70.0], 10.0);
    let r = Renderer::new(&world, PinholeCamera::EUROC_CAM0, &Extrinsic::identity())
        .with_albedo(Box::new(|_, _, _| 0.5));
    let img: Vec<u8> = r
        .radiance(
            &view_along_x(Vec3::new(0.0, 0.0, 50.0)),
            &RenderOptions::default(),
        )
        .iter()
        .map(|&l| (255.0 * l).round() as u8)
        .collect();
    assert_eq!(shi_tomasi_count(&img, 752, 480, min_eig), 0);
}

/// One filtered sample per pixel (plus edge samples) stays close to a 4x4 supersampled
/// reference: the texture pre-filter removes what would alias.
#[test]
fn prefiltered_render_is_close_to_supersampled() {
    let out = sim(Scenario::Robot, 1, 4.0);
    let frames = camera_frames(&out);
    let r = Renderer::new(
        &out.world,
        out.dataset.calib.camera,
        &out.dataset.calib.t_bc,
    );
    let k = frames.len() - 1;
    let view = r.view(&out.trajectory.eval(frames[k].1));
    let fast = r.radiance(&view, &RenderOptions::default());
    let reference = r.radiance(
        &view,
        &RenderOptions {
            supersample: 4,
            edge_samples: 4,
            ..RenderOptions::default()
        },
    );
    let mut d: Vec<f64> = fast
        .iter()
        .zip(&reference)
        .map(|(a, b)| 255.0 * f64::from((a - b).abs()))
        .collect();
    let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
    d.sort_by(f64::total_cmp);
    let p99 = d[d.len() * 99 / 100];
    eprintln!("1 sample vs 4x4: rms {rms:.2} grey levels, p99 {p99:.2}");
    assert!(rms < 3.0 && p99 < 12.0, "rms {rms}, p99 {p99}");
}

/// Rendering time per frame on one thread (`cargo test --release ... render_speed -- --ignored
/// --nocapture`).
#[test]
#[ignore = "a timing report, not a check"]
fn render_speed() {
    for (sc, seed) in [
        (Scenario::Robot, 1),
        (Scenario::Handheld, 1),
        (Scenario::Vehicle, 1),
    ] {
        let out = sim(sc, seed, 20.0);
        let frames = camera_frames(&out);
        let r = Renderer::new(
            &out.world,
            out.dataset.calib.camera,
            &out.dataset.calib.t_bc,
        );
        let t0 = sequence::thread_cpu_s().unwrap_or(0.0);
        let n = 12;
        for k in 0..n {
            let i = k * (frames.len() - 1) / (n - 1);
            let _ = r.render_frame(
                &out.trajectory,
                frames[i].1,
                i as u64,
                1,
                &RenderOptions::default(),
            );
        }
        let cpu = sequence::thread_cpu_s().unwrap_or(0.0) - t0;
        eprintln!(
            "{}: {:.1} ms CPU per frame",
            sc.name(),
            cpu * 1e3 / n as f64
        );
    }
}

/// Motion blur smooths a moving frame, the exposure gain varies by the requested amount, and the
/// pixel noise has the requested standard deviation.
#[test]
fn options_have_their_effect() {
    let out = sim(Scenario::Handheld, 6, 6.0);
    let frames = camera_frames(&out);
    let r = Renderer::new(
        &out.world,
        out.dataset.calib.camera,
        &out.dataset.calib.t_bc,
    );
    let (k, t) = fastest_rotation(&out, &frames);
    let render = |o: RenderOptions| r.render_frame(&out.trajectory, t, k as u64, 6, &o);
    let energy = |px: &[u8]| {
        let mut e = 0.0;
        for y in 0..479 {
            for x in 0..751 {
                let g = |dx: usize, dy: usize| f64::from(px[(y + dy) * 752 + x + dx]);
                e += (g(1, 0) - g(0, 0)).powi(2) + (g(0, 1) - g(0, 0)).powi(2);
            }
        }
        e / (751.0 * 479.0)
    };
    let sharp = render(RenderOptions::default());
    let blurred = render(RenderOptions {
        motion_blur_s: 0.02,
        ..RenderOptions::default()
    });
    let (es, eb) = (energy(&sharp), energy(&blurred));
    eprintln!("gradient energy sharp {es:.1}, 20 ms blur {eb:.1}");
    assert!(eb < 0.8 * es, "blur did not smooth: {es} -> {eb}");

    // Exposure: log-gain standard deviation over 10 minutes close to the option.
    let logs: Vec<f64> = (0..6000)
        .map(|i| exposure_gain(6, 0.2, i as f64 * 0.1).ln())
        .collect();
    let mean = logs.iter().sum::<f64>() / logs.len() as f64;
    let sd = (logs.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / logs.len() as f64).sqrt();
    assert!((0.14..0.26).contains(&sd), "log gain sd {sd}");
    assert_eq!(exposure_gain(6, 0.0, 3.0), 1.0);

    // Noise: the difference to the noise-free frame has the requested sigma (unclipped pixels).
    let noisy = render(RenderOptions {
        noise_grey: 3.0,
        ..RenderOptions::default()
    });
    let d: Vec<f64> = sharp
        .iter()
        .zip(&noisy)
        .filter(|(a, _)| (15..240).contains(*a))
        .map(|(a, b)| f64::from(*b) - f64::from(*a))
        .collect();
    let sd = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
    assert!((2.8..3.2).contains(&sd), "noise sd {sd}");
}

/// The frame with the fastest rotation: its index and trajectory time.
fn fastest_rotation(out: &SimOutput, frames: &[(i64, f64)]) -> (usize, f64) {
    let w = |i: usize| out.trajectory.eval(frames[i].1).omega_b.norm();
    let k = (0..frames.len())
        .max_by(|&a, &b| w(a).total_cmp(&w(b)))
        .unwrap();
    (k, frames[k].1)
}

#[test]
fn a_rolling_shutter_renders_each_row_from_its_own_pose() {
    let out = sim(Scenario::Handheld, 6, 6.0);
    let frames = camera_frames(&out);
    let mut cam = out.dataset.calib.camera;
    cam.readout_s = 0.03;
    let r = Renderer::new(&out.world, cam, &out.dataset.calib.t_bc);
    let (_, t) = fastest_rotation(&out, &frames);
    // No anti-aliasing pass: it compares a pixel with its neighbours, which other rows see.
    let opts = RenderOptions {
        supersample: 1,
        edge_samples: 0,
        ..RenderOptions::default()
    };
    let rolling = r.radiance_rolling(&out.trajectory, t, &opts);
    let w = cam.width as usize;
    let row = |img: &[f32], y: usize| img[y * w..(y + 1) * w].to_vec();
    let global_at = |dt: f64| r.radiance(&r.view(&out.trajectory.eval(t + dt)), &opts);
    let mid = global_at(0.0);
    let mut moved = 0;
    for y in [0usize, 15, 16, 200, 479] {
        let own = global_at(cam.row_time_s(y as f64));
        assert!(
            row(&rolling, y) == row(&own, y),
            "row {y} is not its own pose's"
        );
        moved += usize::from(row(&rolling, y) != row(&mid, y));
    }
    assert!(
        moved >= 3,
        "only {moved} of 5 rows differ from the middle row's pose"
    );
}

/// Bilinear sample of an image (f64 grey levels) at `(x, y)`; `None` outside.
fn bilinear(img: &[f64], w: usize, h: usize, x: f64, y: f64) -> Option<f64> {
    if !(x >= 0.0 && y >= 0.0 && x < (w - 1) as f64 && y < (h - 1) as f64) {
        return None;
    }
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let at = |xx: usize, yy: usize| img[yy * w + xx];
    Some(
        (1.0 - fy) * ((1.0 - fx) * at(x0, y0) + fx * at(x0 + 1, y0))
            + fy * ((1.0 - fx) * at(x0, y0 + 1) + fx * at(x0 + 1, y0 + 1)),
    )
}

/// Translation-only Lucas-Kanade of the 15x15 patch around integer pixel `p` of `a` into `b`,
/// started at `q0`.
fn lk(a: &[f64], b: &[f64], w: usize, h: usize, p: [usize; 2], q0: [f64; 2]) -> Option<[f64; 2]> {
    let r = 7i64;
    let mut q = q0;
    for _ in 0..30 {
        let (mut hxx, mut hxy, mut hyy, mut bx, mut by) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for dy in -r..=r {
            for dx in -r..=r {
                let t = a[(p[1] as i64 + dy) as usize * w + (p[0] as i64 + dx) as usize];
                let (x, y) = (q[0] + dx as f64, q[1] + dy as f64);
                let i = bilinear(b, w, h, x, y)?;
                let gx = 0.5 * (bilinear(b, w, h, x + 1.0, y)? - bilinear(b, w, h, x - 1.0, y)?);
                let gy = 0.5 * (bilinear(b, w, h, x, y + 1.0)? - bilinear(b, w, h, x, y - 1.0)?);
                let e = t - i;
                hxx += gx * gx;
                hxy += gx * gy;
                hyy += gy * gy;
                bx += gx * e;
                by += gy * e;
            }
        }
        let det = hxx * hyy - hxy * hxy;
        if det.abs() < 1e-9 {
            return None;
        }
        let (sx, sy) = ((hyy * bx - hxy * by) / det, (hxx * by - hxy * bx) / det);
        q = [q[0] + sx, q[1] + sy];
        if sx.abs() + sy.abs() < 1e-5 {
            return Some(q);
        }
    }
    Some(q)
}

/// Rendered content moves as the image truth says: a plain Lucas-Kanade tracker on consecutive
/// rendered frames lands on the true transfer of well-textured points away from depth edges
/// (what an image front end's accuracy is measured against).
#[test]
fn rendered_content_follows_the_truth() {
    let mut all = Vec::new();
    for (sc, seed) in [(Scenario::Robot, 1), (Scenario::Handheld, 2)] {
        let out = sim(sc, seed, 5.0);
        let truth = ImageTruth::new(&out);
        let frames = camera_frames(&out);
        let r = truth.renderer();
        for i in [40usize, 80] {
            let img = |k: usize| -> Vec<f64> {
                r.render_frame(
                    &out.trajectory,
                    frames[k].1,
                    k as u64,
                    seed,
                    &RenderOptions::default(),
                )
                .iter()
                .map(|&v| f64::from(v))
                .collect()
            };
            let (a, b) = (img(i), img(i + 1));
            let depth = truth.depth_map(i).unwrap();
            let a8: Vec<u8> = a.iter().map(|&v| v as u8).collect();
            let mut errs = Vec::new();
            for (x, y) in shi_tomasi_corners(&a8, 752, 480, 25.0) {
                if !(12..740).contains(&x) || !(12..468).contains(&y) {
                    continue;
                }
                // Skip points near a depth discontinuity (occlusion boundaries): no jump of more
                // than 3 % between neighbouring pixels of the window.
                let dep = |xx: i64, yy: i64| f64::from(depth[yy as usize * 752 + xx as usize]);
                let mut flat = true;
                for dy in -9i64..=9 {
                    for dx in -9i64..=9 {
                        let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                        let d = dep(xx, yy);
                        flat &= d.is_finite()
                            && (dep(xx + 1, yy) - d).abs() < 0.03 * d
                            && (dep(xx, yy + 1) - d).abs() < 0.03 * d;
                    }
                }
                let Some(q) = truth.transfer(i, [x as f64, y as f64], i + 1) else {
                    continue;
                };
                if !flat || q[0] < 12.0 || q[1] < 12.0 || q[0] > 739.0 || q[1] > 467.0 {
                    continue;
                }
                if let Some(t) = lk(
                    &a,
                    &b,
                    752,
                    480,
                    [x, y],
                    [q[0].round() + 0.3, q[1].round() - 0.4],
                ) {
                    errs.push(((t[0] - q[0]).powi(2) + (t[1] - q[1]).powi(2)).sqrt());
                }
            }
            all.extend(errs);
        }
    }
    all.sort_by(f64::total_cmp);
    let (med, p90) = (all[all.len() / 2], all[all.len() * 9 / 10]);
    eprintln!(
        "LK on rendered frames vs truth: {} points, median {med:.3} px, p90 {p90:.3} px",
        all.len()
    );
    assert!(all.len() > 200, "{}", all.len());
    assert!(med < 0.1 && p90 < 0.3, "median {med}, p90 {p90}");
}

/// Writes one frame per scenario as PNG for looking at (`POVINS_RENDER_DUMP=dir`, default
/// `target/render-dump`).
#[test]
#[ignore = "writes pictures for a person to look at"]
fn dump_frames() {
    let dir = std::env::var("POVINS_RENDER_DUMP").unwrap_or_else(|_| "target/render-dump".into());
    std::fs::create_dir_all(&dir).unwrap();
    for (sc, seed) in [
        (Scenario::Robot, 1),
        (Scenario::Handheld, 1),
        (Scenario::Vehicle, 1),
    ] {
        let out = sim(sc, seed, 10.0);
        let frames = camera_frames(&out);
        let c = &out.dataset.calib;
        let r = Renderer::new(&out.world, c.camera, &c.t_bc);
        let k = frames.len() / 2;
        let px = r.render_frame(
            &out.trajectory,
            frames[k].1,
            k as u64,
            seed,
            &RenderOptions::default(),
        );
        let p = std::path::Path::new(&dir).join(format!("{}-{k}.png", sc.name()));
        povins_platform::euroc::write_png_mono8(&p, c.camera.width, c.camera.height, &px).unwrap();
    }
}
