//! Model files and importers: the SMPL-family `.npz` model file ([`modelfile`]) and the MakeHuman
//! assets turned into lfit models (readers, body and face import, the rigs' ranges of motion).
//!
//! The entry points are reached through their module (`modelfile::load`, `modelfile::save`,
//! `makehuman_import::import`, `makehuman_face::import_face`); their options and reports are here.

pub mod makehuman;
pub mod makehuman_face;
pub mod makehuman_import;
pub mod makehuman_rom;
pub mod modelfile;

pub use makehuman_face::{FaceImportOptions, FaceImportReport};
pub use makehuman_import::{ImportOptions, ImportReport};

impl crate::template::Template {
    /// Loads a model: a directory with `template.obj` + `rig.json`
    /// ([`crate::template::Template::load_dir`]), or a model file in the SMPL-family `.npz`
    /// layout ([`modelfile`]). A pickled `.pkl` is refused with a hint.
    pub fn load(path: &std::path::Path) -> crate::error::Result<Self> {
        if path.is_dir() {
            return Self::load_dir(path);
        }
        modelfile::load(path)
    }
}
