//! The page's files, embedded in the binary so the page works with no network: `web/` in the
//! repository (the page and its script) and `web/vendor/` (three.js and Spark, pinned, with
//! their licences; `scripts/vendor-web` re-fetches them from npm). With `LHMPP_WEB_DIR` set
//! (a developer's `web/` folder) the same paths are read from there instead, so the page can
//! be changed without rebuilding.

use std::borrow::Cow;

/// `(path, bytes, content type)` of every file served.
const FILES: &[(&str, &[u8], &str)] = &[
    ("/", include_bytes!("../../web/index.html"), HTML),
    ("/app.js", include_bytes!("../../web/app.js"), JS),
    (
        "/vendor/three/three.module.min.js",
        include_bytes!("../../web/vendor/three/three.module.min.js"),
        JS,
    ),
    (
        "/vendor/three/three.core.min.js",
        include_bytes!("../../web/vendor/three/three.core.min.js"),
        JS,
    ),
    (
        "/vendor/three/addons/controls/OrbitControls.js",
        include_bytes!("../../web/vendor/three/addons/controls/OrbitControls.js"),
        JS,
    ),
    (
        "/vendor/three/addons/postprocessing/Pass.js",
        include_bytes!("../../web/vendor/three/addons/postprocessing/Pass.js"),
        JS,
    ),
    (
        "/vendor/three/LICENSE",
        include_bytes!("../../web/vendor/three/LICENSE"),
        TEXT,
    ),
    (
        "/vendor/spark/spark.module.min.js",
        include_bytes!("../../web/vendor/spark/spark.module.min.js"),
        JS,
    ),
    (
        "/vendor/spark/LICENSE",
        include_bytes!("../../web/vendor/spark/LICENSE"),
        TEXT,
    ),
    (
        "/vendor/VERSIONS",
        include_bytes!("../../web/vendor/VERSIONS"),
        TEXT,
    ),
];

const HTML: &str = "text/html; charset=utf-8";
const JS: &str = "text/javascript; charset=utf-8";
const TEXT: &str = "text/plain; charset=utf-8";

/// The bytes and content type of the file served at `path`.
pub fn file(path: &str) -> Option<(Cow<'static, [u8]>, &'static str)> {
    let (_, bytes, kind) = FILES.iter().find(|(p, _, _)| *p == path)?;
    if let Some(dir) = std::env::var_os("LHMPP_WEB_DIR") {
        let on_disk = if path == "/" { "/index.html" } else { path };
        let full = std::path::Path::new(&dir).join(on_disk.trim_start_matches('/'));
        match std::fs::read(&full) {
            Ok(b) => return Some((Cow::Owned(b), kind)),
            Err(e) => tracing::warn!("LHMPP_WEB_DIR: {}: {e}", full.display()),
        }
    }
    Some((Cow::Borrowed(*bytes), kind))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_and_every_module_it_imports_are_served() {
        let page = file("/").unwrap().0;
        let page = std::str::from_utf8(&page).unwrap();
        for import in [
            "/app.js",
            "/vendor/three/three.module.min.js",
            "/vendor/spark/spark.module.min.js",
        ] {
            assert!(page.contains(import), "{import}");
            assert!(file(import).is_some(), "{import}");
        }
        // three's module imports its core; Spark imports three's Pass add-on.
        let three = file("/vendor/three/three.module.min.js").unwrap().0;
        let three = std::str::from_utf8(&three).unwrap();
        assert!(three.contains("./three.core.min.js"));
        assert!(file("/vendor/three/addons/postprocessing/Pass.js").is_some());
        assert!(file("/vendor/spark/LICENSE").is_some() && file("/vendor/three/LICENSE").is_some());
        assert!(file("/nope").is_none());
    }
}
