//! The frozen supervised reference and the share of the way to it that the images go (issue 71).
//!
//! A reference file holds, per scene, R: the symmetric distance CD = (d + d′)/2 that supervision
//! reaches (the better of DLF† and the joint stage given the truth, means over seeds), per
//! window, measured under a stated set of rules. With D the pretrained DLF under the run's
//! rules and NF the grounded one, both from the run's own report,
//! g = (CD_D − CD_NF) / (CD_D − CD_R): 0 where the images add nothing, 1 where they go as far as
//! supervision. The file is read as every input is ([`neurofluid_core::input_file`]), and every
//! fault names the file, the field and what was expected.
//!
//! ```toml
//! # what R is and how it was measured
//! description = "R: the better of DLF† and the joint stage given the truth, seeds 10–12"
//! rules = "the walls"
//! [scenes.watercube]               # the scene's manifest name
//! particles = 2744                 # optional: the scene it was measured on
//! grounding = 12.5                 # CD_R over the grounding window (t < 50)
//! prediction = 21.0                # CD_R over the prediction window
//! source = "DLF† at 4× the budget"  # optional: which reference gave it
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// One scene's reference values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneReference {
    /// The particles of the scene it was measured on (checked against the run's where given).
    #[serde(default)]
    pub particles: Option<usize>,
    /// CD_R over the grounding window.
    pub grounding: f64,
    /// CD_R over the prediction window.
    pub prediction: f64,
    /// Which reference gave it.
    #[serde(default)]
    pub source: Option<String>,
}

/// A reference file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceFile {
    /// What R is and how it was measured.
    pub description: String,
    /// The rules it was measured under, as the report words them.
    #[serde(default)]
    pub rules: Option<String>,
    /// Per scene (its manifest name).
    pub scenes: BTreeMap<String, SceneReference>,
}

/// Why a reference file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    /// Unreadable, or not a reference file.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: PathBuf,
        /// What was wrong.
        message: String,
    },
}

impl ReferenceError {
    /// What is wrong with the file at `path`.
    fn at(path: &Path, message: String) -> Self {
        Self::File {
            path: path.to_path_buf(),
            message,
        }
    }
}

impl ReferenceFile {
    /// Reads and checks `path`.
    pub fn read(path: &Path) -> Result<Self, ReferenceError> {
        let fault = |message| ReferenceError::at(path, message);
        let text =
            neurofluid_core::input_file::read_string(path).map_err(|e| fault(e.to_string()))?;
        let file: Self = toml::from_str(&text).map_err(|e| {
            fault(format!(
                "expected a reference file (description, [scenes.<name>] grounding and \
                 prediction): {}",
                neurofluid_core::paths::cut(&e.to_string(), 1000)
            ))
        })?;
        for (name, s) in &file.scenes {
            for (field, v) in [("grounding", s.grounding), ("prediction", s.prediction)] {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(fault(format!(
                        "scenes.{}.{field}: expected a distance ≥ 0, got {v}",
                        neurofluid_core::paths::cut(name, 80)
                    )));
                }
            }
        }
        Ok(file)
    }

    /// The share of the way to the reference for `scene` with `particles` particles, from the
    /// run's CD of the pretrained DLF and of NeuroFluid per window.
    pub fn gap_share(
        &self,
        path: &Path,
        scene: &str,
        particles: usize,
        dlf: [Option<f64>; 2],
        neurofluid: [Option<f64>; 2],
    ) -> Result<GapShare, ReferenceError> {
        let fault = |message| ReferenceError::at(path, message);
        let r = self.scenes.get(scene).ok_or_else(|| {
            fault(format!(
                "no [scenes.{scene}] (the run's scene); the file has [{}]",
                self.scenes
                    .keys()
                    .take(20)
                    .map(|k| neurofluid_core::paths::shown(k))
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })?;
        if let Some(n) = r.particles.filter(|&n| n != particles) {
            return Err(fault(format!(
                "scenes.{scene}.particles: measured on {n} particles, the run's scene has \
                 {particles}: another scene of the same name"
            )));
        }
        let window = |k: usize, reference: f64| {
            let (d, nf) = (dlf[k]?, neurofluid[k]?);
            Some(WindowGap {
                dlf: d,
                neurofluid: nf,
                reference,
                share: share(d, nf, reference),
            })
        };
        Ok(GapShare {
            file: path.display().to_string(),
            source: r.source.clone(),
            grounding: window(0, r.grounding),
            prediction: window(1, r.prediction),
        })
    }
}

/// g = (D − NF) / (D − R); `None` where the reference is not below D (no gap to close).
pub fn share(dlf: f64, neurofluid: f64, reference: f64) -> Option<f64> {
    let gap = dlf - reference;
    (gap > 0.0).then(|| (dlf - neurofluid) / gap)
}

/// One window's symmetric distances and g.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindowGap {
    /// CD of the pretrained DLF under the run's rules.
    pub dlf: f64,
    /// CD of NeuroFluid.
    pub neurofluid: f64,
    /// CD of the reference.
    pub reference: f64,
    /// g; `None` where the reference is not below the DLF.
    pub share: Option<f64>,
}

/// The share of the way to supervision, per window, with what it was measured against.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GapShare {
    /// The reference file.
    pub file: String,
    /// Which reference gave the scene's values.
    #[serde(default)]
    pub source: Option<String>,
    /// Over the grounding window.
    pub grounding: Option<WindowGap>,
    /// Over the prediction window.
    pub prediction: Option<WindowGap>,
}

impl GapShare {
    /// The report's line.
    pub fn markdown(&self, windows: [(usize, usize); 2]) -> String {
        let part = |w: &Option<WindowGap>, (a, b): (usize, usize)| match w {
            None => format!("t = {a}–{b}: not evaluated"),
            Some(w) => format!(
                "t = {a}–{b}: g = {} (CD: DLF {:.2}, NeuroFluid {:.2}, reference {:.2})",
                w.share
                    .map_or("– (the reference is not below DLF)".into(), |g| format!(
                        "{g:.2}"
                    )),
                w.dlf,
                w.neurofluid,
                w.reference
            ),
        };
        format!(
            "The share of the way to supervision the images went, g = (CD_DLF − CD_NeuroFluid) / \
             (CD_DLF − CD_reference), CD = (d + d′)/2, against `{}`{}: {}; {}.",
            crate::formats::markup::markdown_text(&self.file),
            self.source
                .as_ref()
                .map(|s| format!(" ({})", crate::formats::markup::markdown_text(s)))
                .unwrap_or_default(),
            part(&self.grounding, windows[0]),
            part(&self.prediction, windows[1])
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(text: &str) -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("reference.toml");
        std::fs::write(&path, text).unwrap();
        (dir, path)
    }

    const GOOD: &str = "description = \"R\"\n[scenes.watercube]\nparticles = 2744\n\
                        grounding = 10.0\nprediction = 20.0\nsource = \"DLF† at 4×\"\n";

    /// g is 0 at DLF, 1 at the reference, ½ half way; undefined where the reference is no
    /// better than DLF.
    #[test]
    fn the_share_is_the_way_from_dlf_to_the_reference() {
        assert_eq!(share(30.0, 30.0, 10.0), Some(0.0));
        assert_eq!(share(30.0, 10.0, 10.0), Some(1.0));
        assert_eq!(share(30.0, 20.0, 10.0), Some(0.5));
        assert_eq!(share(30.0, 35.0, 10.0), Some(-0.25));
        assert_eq!(share(10.0, 8.0, 12.0), None);
        let (_d, path) = write(GOOD);
        let file = ReferenceFile::read(&path).unwrap();
        let g = file
            .gap_share(
                &path,
                "watercube",
                2744,
                [Some(30.0), Some(40.0)],
                [Some(20.0), None],
            )
            .unwrap();
        assert_eq!(g.grounding.as_ref().unwrap().share, Some(0.5));
        assert!(g.prediction.is_none());
        let md = g.markdown([(1, 49), (50, 59)]);
        assert!(md.contains("t = 1–49: g = 0.50"), "{md}");
        assert!(md.contains("DLF† at 4×"), "{md}");
    }

    /// A wrong scene, another scene of the same name, a negative distance and a file that is
    /// no reference each name the file and the field.
    #[test]
    fn faults_name_the_file_and_the_field() {
        let (_d, path) = write(GOOD);
        let file = ReferenceFile::read(&path).unwrap();
        let err = |r: Result<GapShare, ReferenceError>| r.unwrap_err().to_string();
        let e = err(file.gap_share(&path, "honeycone", 2744, [None; 2], [None; 2]));
        assert!(
            e.contains("reference.toml") && e.contains("scenes.honeycone"),
            "{e}"
        );
        let e = err(file.gap_share(&path, "watercube", 11_000, [None; 2], [None; 2]));
        assert!(e.contains("scenes.watercube.particles"), "{e}");
        let (_d, bad) = write(&GOOD.replace("grounding = 10.0", "grounding = -1.0"));
        let e = ReferenceFile::read(&bad).unwrap_err().to_string();
        assert!(e.contains("scenes.watercube.grounding"), "{e}");
        let (_d, bad) = write("[scenes.x]\ngrounding = 1.0\n");
        let e = ReferenceFile::read(&bad).unwrap_err().to_string();
        assert!(
            e.contains("reference.toml") && e.contains("expected a reference"),
            "{e}"
        );
    }
}
