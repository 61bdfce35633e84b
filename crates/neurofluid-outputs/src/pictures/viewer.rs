//! A recording of an evaluation that opens in any browser, with nothing to install:
//! `eval/viewer.html` holds the particle sets of every frame (truth, DLF, NeuroFluid), the test
//! cameras, the per-frame distances, the training loss curves and links to the renders, and a
//! small player (orbit, zoom, timeline, play) drawn on a canvas.
//!
//! The particles are stored as little-endian u16 coordinates over the bounding box of all sets
//! (base64), so a 60-frame scene of 10k particles stays near 15 MB; the quantisation step is
//! `(hi − lo) / 65535` per axis, far below a particle radius.

use std::path::Path;

use anyhow::Context;
use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use neurofluid_core::camera::Camera;
use serde::{Deserialize, Serialize};

use crate::metrics_log::MetricsRow;
use crate::report::{EvalReport, Rollout};

/// A particle set to record: its name, CSS colour and positions per frame.
pub type TrackInput<'a> = (&'a str, &'a str, &'a [Vec<[f32; 3]>]);

/// One particle set over time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Track {
    /// Its name (`truth`, `DLF`, `NeuroFluid`).
    pub name: String,
    /// CSS colour.
    pub colour: String,
    /// Particles per frame.
    pub particles: usize,
    /// base64 of `frames × particles × 3` u16 coordinates.
    pub data: String,
}

/// A curve over the frames (e.g. d of a model).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Curve {
    /// Its name.
    pub name: String,
    /// CSS colour.
    pub colour: String,
    /// `(t, value)` points.
    pub points: Vec<(usize, f64)>,
}

impl Curve {
    fn new(name: &str, colour: &str, points: Vec<(usize, f64)>) -> Self {
        Self {
            name: name.to_string(),
            colour: colour.to_string(),
            points,
        }
    }
}

/// A camera the viewer can look through.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewCamera {
    /// View name.
    pub view: String,
    /// Camera centre.
    pub eye: [f32; 3],
    /// Horizontal field of view (radians).
    pub fov_x: f32,
    /// Renders of this view by frame: `(t, path relative to the viewer)`.
    pub renders: Vec<(usize, String)>,
}

/// Everything the viewer shows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Recording {
    /// Title line.
    pub title: String,
    /// Number of frames.
    pub frames: usize,
    /// Particle radius (world units).
    pub radius: f32,
    /// Lower corner of the quantisation box.
    pub lo: [f32; 3],
    /// Upper corner of the quantisation box.
    pub hi: [f32; 3],
    /// The particle sets.
    pub tracks: Vec<Track>,
    /// Curves under the player, over the frames.
    pub curves: Vec<Curve>,
    /// Training curves (loss over steps), one per stage.
    #[serde(default)]
    pub training: Vec<Curve>,
    /// Cameras (the first is the initial view).
    pub cameras: Vec<ViewCamera>,
}

impl Recording {
    /// A recording of `sets` (name, colour, positions per frame; every set has the same frames).
    pub fn new(title: &str, radius: f32, sets: &[TrackInput<'_>]) -> anyhow::Result<Self> {
        let frames = sets.first().map_or(0, |s| s.2.len());
        anyhow::ensure!(
            sets.iter().all(|s| s.2.len() == frames),
            "every particle set needs the same frames"
        );
        let all = || sets.iter().flat_map(|s| s.2.iter().flatten());
        anyhow::ensure!(
            all().flatten().all(|v| v.is_finite()),
            "particle positions must be finite"
        );
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in all() {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if frames == 0 || !lo[0].is_finite() {
            lo = [0.0; 3];
            hi = [1.0; 3];
        }
        let span: [f32; 3] = std::array::from_fn(|a| (hi[a] - lo[a]).max(1e-6));
        let tracks = sets
            .iter()
            .map(|(name, colour, frames)| {
                let particles = frames.first().map_or(0, Vec::len);
                anyhow::ensure!(
                    frames.iter().all(|f| f.len() == particles),
                    "{name}: the particle count changes between frames"
                );
                let mut bytes = Vec::with_capacity(frames.len() * particles * 6);
                for p in frames.iter().flatten() {
                    for a in 0..3 {
                        let q = ((p[a] - lo[a]) / span[a] * 65535.0).round() as u16;
                        bytes.extend_from_slice(&q.to_le_bytes());
                    }
                }
                Ok(Track {
                    name: name.to_string(),
                    colour: colour.to_string(),
                    particles,
                    data: STANDARD.encode(bytes),
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        Ok(Self {
            title: title.to_string(),
            frames,
            radius,
            lo,
            hi,
            tracks,
            curves: Vec::new(),
            training: Vec::new(),
            cameras: Vec::new(),
        })
    }

    /// Adds a camera to look through, with its renders.
    pub fn with_camera(
        mut self,
        view: &str,
        camera: &Camera,
        renders: Vec<(usize, String)>,
    ) -> Self {
        self.cameras.push(ViewCamera {
            view: view.to_string(),
            eye: camera.origin(),
            fov_x: 2.0 * (0.5 * camera.width as f32 / camera.fx).atan(),
            renders,
        });
        self
    }

    /// Adds a curve over the frames.
    pub fn with_curve(mut self, name: &str, colour: &str, points: Vec<(usize, f64)>) -> Self {
        self.curves.push(Curve::new(name, colour, points));
        self
    }

    /// Adds a training curve (x = step).
    pub fn with_training_curve(
        mut self,
        name: &str,
        colour: &str,
        points: Vec<(usize, f64)>,
    ) -> Self {
        self.training.push(Curve::new(name, colour, points));
        self
    }

    /// `report`'s d curves: NeuroFluid's, then DLF's and DLF†'s where evaluated.
    pub fn with_distance_curves(mut self, report: &EvalReport) -> Self {
        self = self.with_curve(
            "NeuroFluid d",
            "#2e9e5b",
            report
                .frames
                .iter()
                .filter_map(|f| Some((f.t, Rollout::NeuroFluid.of(f)?)))
                .collect(),
        );
        for (model, colour) in [
            (Rollout::Dlf, "#d9822b"),
            (Rollout::SupervisedDlf, "#803caa"),
        ] {
            let points: Vec<(usize, f64)> = report
                .frames
                .iter()
                .filter_map(|f| model.of(f).map(|d| (f.t, d)))
                .collect();
            if !points.is_empty() {
                self = self.with_curve(&format!("{} d", model.label()), colour, points);
            }
        }
        self
    }

    /// The loss curves of a metrics log's `rows`, one per `(stage, colour)` with finite losses.
    pub fn with_loss_curves(mut self, rows: &[MetricsRow], stages: &[(&str, &str)]) -> Self {
        for (stage, colour) in stages {
            let points: Vec<(usize, f64)> = rows
                .iter()
                .filter(|r| r.stage == *stage && r.loss.is_finite())
                .map(|r| (r.step as usize, r.loss))
                .collect();
            if !points.is_empty() {
                self = self.with_training_curve(&format!("{stage} loss"), colour, points);
            }
        }
        self
    }

    /// The positions of track `k` at frame `t`, decoded (to the quantisation step).
    pub fn positions(&self, k: usize, t: usize) -> anyhow::Result<Vec<[f32; 3]>> {
        let track = self.tracks.get(k).context("no such track")?;
        let bytes = STANDARD
            .decode(&track.data)
            .context("track data is not base64")?;
        let n = track.particles;
        let start = t * n * 6;
        let chunk = bytes
            .get(start..start + n * 6)
            .context("no such frame in the track")?;
        let span: [f32; 3] = std::array::from_fn(|a| (self.hi[a] - self.lo[a]).max(1e-6));
        Ok(chunk
            .chunks_exact(6)
            .map(|c| {
                std::array::from_fn(|a| {
                    let q = u16::from_le_bytes([c[2 * a], c[2 * a + 1]]);
                    self.lo[a] + q as f32 / 65535.0 * span[a]
                })
            })
            .collect())
    }

    /// Writes the viewer page atomically.
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        // `<`, `>` and `&` only occur inside JSON strings, where their \u escapes mean the
        // same: no text of the recording can close the script element or open a tag
        let json = serde_json::to_string(self)?
            .replace('<', "\\u003c")
            .replace('>', "\\u003e")
            .replace('&', "\\u0026");
        let html = PAGE
            .replace("{{TITLE}}", &crate::formats::markup::html_text(&self.title))
            .replace("{{DATA}}", &json);
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        neurofluid_core::atomic::write_bytes(path, html.as_bytes())
            .with_context(|| format!("writing {}", path.display()))
    }

    /// Reads the recording back from a viewer page.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let html = neurofluid_core::input_file::read_string(path)
            .with_context(|| format!("reading {}", path.display()))?;
        let start = html
            .find(DATA_OPEN)
            .with_context(|| format!("{}: no recording in the page", path.display()))?
            + DATA_OPEN.len();
        let end = start
            + html[start..]
                .find("</script>")
                .with_context(|| format!("{}: unterminated recording", path.display()))?;
        serde_json::from_str(&html[start..end])
            .with_context(|| format!("{}: malformed recording", path.display()))
    }
}

const DATA_OPEN: &str = "<script id=\"recording\" type=\"application/json\">";

/// The page: the recording as JSON and a canvas player.
const PAGE: &str = r##"<!doctype html>
<html><head><meta charset="utf-8"><title>{{TITLE}}</title>
<style>
body{font:14px system-ui,sans-serif;margin:12px;background:#fafafa;color:#222}
#panels{display:flex;gap:8px;flex-wrap:wrap}
.panel{background:#fff;border:1px solid #ddd}
.panel h3{margin:4px 8px;font-size:13px}
canvas{display:block;cursor:grab}
#bar{margin:8px 0;display:flex;gap:8px;align-items:center}
#t{flex:1}
#renders img{image-rendering:pixelated;border:1px solid #ddd;margin-right:6px}
svg{background:#fff;border:1px solid #ddd}
</style></head><body>
<h2>{{TITLE}}</h2>
<div id="panels"></div>
<div id="bar"><button id="play">play</button><input id="t" type="range" min="0" value="0">
<span id="label"></span><select id="cam"></select></div>
<div id="renders"></div>
<svg id="curves" width="720" height="180"></svg>
<svg id="training" width="720" height="180"></svg>
<p>Drag to orbit, wheel to zoom; the camera menu looks through a test camera; <code>#t=40</code>
after the file name opens frame 40. Colours: one per particle set; the curves are d (× 1000)
per frame.</p>
<script id="recording" type="application/json">{{DATA}}</script>
<script>
const R = JSON.parse(document.getElementById('recording').textContent);
// every text of the recording that goes into markup passes through esc (the rest are DOM nodes)
const esc = v => String(v).replace(/[&<>"']/g, ch => '&#'+ch.charCodeAt(0)+';');
const span = [0,1,2].map(a => Math.max(R.hi[a]-R.lo[a], 1e-6));
const centre = [0,1,2].map(a => (R.hi[a]+R.lo[a])/2);
const tracks = R.tracks.map(tr => {
  const bin = atob(tr.data), u = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) u[i] = bin.charCodeAt(i);
  const q = new Uint16Array(u.buffer), f = new Float32Array(q.length);
  for (let i = 0; i < q.length; i++) f[i] = R.lo[i%3] + q[i]/65535*span[i%3];
  return {...tr, pos: f};
});
let yaw = 0.6, pitch = 0.35, dist = 3*Math.max(...span), fov = 0.6, t = 0, playing = false;
function lookFrom(eye, fx) {
  const d = [0,1,2].map(a => eye[a]-centre[a]);
  dist = Math.hypot(...d); yaw = Math.atan2(d[0], d[2]);
  pitch = Math.asin(d[1]/dist); fov = fx;
}
const sel = document.getElementById('cam');
R.cameras.forEach((c, i) => { const o = document.createElement('option'); o.value = i; o.textContent = c.view; sel.appendChild(o); });
sel.onchange = () => { const c = R.cameras[sel.value]; lookFrom(c.eye, c.fov_x); draw(); };
if (R.cameras.length) lookFrom(R.cameras[0].eye, R.cameras[0].fov_x);
const W = 320, H = 320, canvases = [];
const panels = document.getElementById('panels');
tracks.forEach(tr => {
  const div = document.createElement('div'); div.className = 'panel';
  const h3 = document.createElement('h3'); h3.style.color = tr.colour; h3.textContent = tr.name;
  div.appendChild(h3);
  const c = document.createElement('canvas'); c.width = W; c.height = H;
  div.appendChild(c); panels.appendChild(div); canvases.push(c);
  let drag = null;
  c.onmousedown = e => drag = [e.clientX, e.clientY, yaw, pitch];
  window.addEventListener('mouseup', () => drag = null);
  window.addEventListener('mousemove', e => { if (!drag) return;
    yaw = drag[2] - (e.clientX-drag[0])*0.01;
    pitch = Math.max(-1.5, Math.min(1.5, drag[3] + (e.clientY-drag[1])*0.01)); draw(); });
  c.onwheel = e => { e.preventDefault(); dist *= Math.exp(e.deltaY*0.001); draw(); };
});
function draw() {
  const eye = [centre[0]+dist*Math.cos(pitch)*Math.sin(yaw), centre[1]+dist*Math.sin(pitch),
               centre[2]+dist*Math.cos(pitch)*Math.cos(yaw)];
  const back = [0,1,2].map(a => (eye[a]-centre[a])/dist);
  let right = [back[2], 0, -back[0]]; const rn = Math.hypot(...right) || 1;
  right = right.map(v => v/rn);
  const up = [back[1]*right[2]-back[2]*right[1], back[2]*right[0]-back[0]*right[2], back[0]*right[1]-back[1]*right[0]];
  const f = 0.5*W/Math.tan(fov/2);
  tracks.forEach((tr, k) => {
    const ctx = canvases[k].getContext('2d');
    ctx.fillStyle = '#fff'; ctx.fillRect(0, 0, W, H);
    const n = tr.particles, base = t*n*3, pts = [];
    for (let i = 0; i < n; i++) {
      const p = [0,1,2].map(a => tr.pos[base+3*i+a]-eye[a]);
      const z = -(p[0]*back[0]+p[1]*back[1]+p[2]*back[2]);
      if (z <= 0) continue;
      pts.push([W/2 + f*(p[0]*right[0]+p[1]*right[1]+p[2]*right[2])/z,
                H/2 - f*(p[0]*up[0]+p[1]*up[1]+p[2]*up[2])/z, z]);
    }
    pts.sort((a, b) => b[2]-a[2]);
    ctx.fillStyle = tr.colour; ctx.strokeStyle = 'rgba(0,0,0,0.25)';
    for (const [x, y, z] of pts) {
      const r = Math.max(1, f*R.radius/z);
      ctx.beginPath(); ctx.arc(x, y, r, 0, 6.283); ctx.fill(); ctx.stroke();
    }
  });
  const vals = R.curves.map(c => { const p = c.points.find(q => q[0] === t); return c.name+' '+(p ? p[1].toFixed(2) : '–'); });
  document.getElementById('label').textContent = 't = '+t+'   '+vals.join('   ');
  const cam = R.cameras[sel.value || 0];
  const ren = cam && cam.renders.find(r => r[0] === t);
  const box = document.getElementById('renders'); box.replaceChildren();
  if (ren) { const img = document.createElement('img'); img.src = ren[1]; img.height = 200;
    img.title = 'render | truth'; box.appendChild(img); }
  drawCurves();
}
function drawCurves() {
  const svg = document.getElementById('curves'), w = 720, h = 180, m = 30;
  const all = R.curves.flatMap(c => c.points);
  if (!all.length) { svg.style.display = 'none'; return; }
  const ymax = Math.max(...all.map(p => p[1])) * 1.05 || 1, tmax = Math.max(R.frames-1, 1);
  const X = x => m + x/tmax*(w-2*m), Y = y => h-m - y/ymax*(h-2*m);
  let s = '<line x1="'+X(t)+'" x2="'+X(t)+'" y1="'+m+'" y2="'+(h-m)+'" stroke="#aaa"/>';
  s += '<text x="4" y="14" font-size="11">d × 1000 (max '+ymax.toFixed(1)+')</text>';
  R.curves.forEach((c, i) => {
    s += '<polyline fill="none" stroke="'+esc(c.colour)+'" stroke-width="2" points="'+c.points.map(p => X(p[0])+','+Y(p[1])).join(' ')+'"/>';
    s += '<text x="'+(w-150)+'" y="'+(16+14*i)+'" font-size="11" fill="'+esc(c.colour)+'">'+esc(c.name)+'</text>';
  });
  svg.innerHTML = s;
}
function drawTraining() {
  const svg = document.getElementById('training'), w = 720, h = 180, m = 30;
  const all = R.training.flatMap(c => c.points).filter(p => p[1] > 0);
  if (!all.length) { svg.style.display = 'none'; return; }
  const lo = Math.log10(Math.min(...all.map(p => p[1]))), hi = Math.log10(Math.max(...all.map(p => p[1])));
  const span = Math.max(hi-lo, 1e-9), xmax = Math.max(...all.map(p => p[0]), 1);
  const X = x => m + x/xmax*(w-2*m), Y = y => h-m - (Math.log10(y)-lo)/span*(h-2*m);
  let s = '<text x="4" y="14" font-size="11">training loss vs step (log; '+Math.pow(10, lo).toExponential(1)+' – '+Math.pow(10, hi).toExponential(1)+')</text>';
  R.training.forEach((c, i) => {
    const pts = c.points.filter(p => p[1] > 0);
    s += '<polyline fill="none" stroke="'+esc(c.colour)+'" stroke-width="1.5" points="'+pts.map(p => X(p[0])+','+Y(p[1])).join(' ')+'"/>';
    s += '<text x="'+(w-150)+'" y="'+(16+14*i)+'" font-size="11" fill="'+esc(c.colour)+'">'+esc(c.name)+'</text>';
  });
  svg.innerHTML = s;
}
drawTraining();
const slider = document.getElementById('t');
slider.max = Math.max(R.frames-1, 0);
const start = location.hash.match(/t=(\d+)/);
if (start) { t = Math.min(+start[1], R.frames-1); slider.value = t; }
slider.oninput = () => { t = +slider.value; draw(); };
document.getElementById('play').onclick = () => { playing = !playing; document.getElementById('play').textContent = playing ? 'pause' : 'play'; };
setInterval(() => { if (!playing) return; t = (t+1) % Math.max(R.frames, 1); slider.value = t; draw(); }, 80);
draw();
</script></body></html>
"##;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recording_reads_back_from_its_page() {
        let truth: Vec<Vec<[f32; 3]>> = (0..3)
            .map(|t| vec![[0.0, t as f32 * 0.1, 0.0], [1.0, 0.5, -0.25]])
            .collect();
        let pred: Vec<Vec<[f32; 3]>> = truth
            .iter()
            .map(|f| f.iter().map(|p| [p[0] + 0.01, p[1], p[2]]).collect())
            .collect();
        let cam = Camera::look_at(32, 32, 0.7, [0.0, 1.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0]);
        let rec = Recording::new(
            "test </script> & co",
            0.025,
            &[("truth", "#36c", &truth), ("NeuroFluid", "#2a2", &pred)],
        )
        .unwrap()
        .with_camera("view_5", &cam, vec![(1, "renders/view_5/t0001.png".into())])
        .with_curve("NeuroFluid", "#2a2", vec![(1, 10.0), (2, 12.5)])
        .with_training_curve("warmup loss", "#36c", vec![(1, 0.5), (2, 0.25)]);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("eval/viewer.html");
        rec.write(&path).unwrap();
        let back = Recording::read(&path).unwrap();
        assert_eq!(back, rec);
        assert_eq!(back.frames, 3);
        assert_eq!(back.training[0].points, [(1, 0.5), (2, 0.25)]);
        // positions survive the quantisation to well under a particle radius
        let step = (1.0f32 + 0.01) / 65535.0;
        for (k, sets) in [&truth, &pred].iter().enumerate() {
            for (t, frame) in sets.iter().enumerate() {
                for (a, b) in back.positions(k, t).unwrap().iter().zip(frame) {
                    assert!(a.iter().zip(b).all(|(x, y)| (x - y).abs() <= step));
                }
            }
        }
        assert!((back.cameras[0].fov_x - 0.7).abs() < 1e-5);
        let html = std::fs::read_to_string(&path).unwrap();
        assert!(html.contains("<title>test &lt;/script&gt; &amp; co</title>"));
        assert!(
            Recording::new(
                "x",
                0.1,
                &[("a", "#000", &truth[..2]), ("b", "#000", &pred)]
            )
            .is_err()
        );
    }

    /// Names from data files (view folders, set names) reach the page as data: the recording
    /// holds no `<`, and the player builds its elements as DOM nodes or through `esc`.
    #[test]
    fn hostile_names_stay_text() {
        let frames = vec![vec![[0.0f32, 0.0, 0.0]]];
        let evil = "v5\"><img src=x onerror=alert(document.cookie)></script><script>x()</script>";
        let cam = Camera::look_at(32, 32, 0.7, [0.0, 1.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0]);
        let rec = Recording::new(evil, 0.025, &[(evil, evil, &frames)])
            .unwrap()
            .with_camera(evil, &cam, vec![(0, format!("renders/{evil}/t0000.png"))])
            .with_curve(evil, evil, vec![(0, 1.0)])
            .with_training_curve(evil, evil, vec![(1, 0.5)]);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("viewer.html");
        rec.write(&path).unwrap();
        let html = std::fs::read_to_string(&path).unwrap();
        assert!(!html.contains("<img"), "a tag from a name reached the page");
        assert_eq!(
            html.matches("<script").count(),
            2,
            "only the page's own scripts"
        );
        assert_eq!(html.matches("</script>").count(), 2);
        let start = html.find(DATA_OPEN).unwrap() + DATA_OPEN.len();
        let end = start + html[start..].find("</script>").unwrap();
        assert!(!html[start..end].contains(['<', '>', '&']));
        // the player concatenates no recording text into markup unescaped
        let script = &html[end..];
        for raw in ["+tr.name", "+c.name", "+c.colour", "+tr.colour", "+ren[1]"] {
            assert!(!script.contains(raw), "{raw} is concatenated into markup");
        }
        assert_eq!(Recording::read(&path).unwrap(), rec);
    }
}
