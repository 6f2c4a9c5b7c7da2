//! `locate_vgg19`'s use of `$NST3D_VGG19`. One test in its own binary, because it sets a
//! process-wide environment variable that other tests read.

use nst3d_weights::{default_vgg19_path, locate_vgg19, WeightsError, FETCH_COMMAND, VGG19_ENV};

#[test]
fn env_override_and_missing_file_errors() {
    let file = std::env::temp_dir().join(format!("nst3d-locate-{}.pth", std::process::id()));
    std::fs::write(&file, b"x").unwrap();
    // SAFETY of ordering: this binary runs only this test, so no thread reads the
    // environment concurrently.
    std::env::set_var(VGG19_ENV, &file);
    assert_eq!(locate_vgg19().unwrap(), file);

    let missing = file.with_extension("missing");
    std::env::set_var(VGG19_ENV, &missing);
    let err = locate_vgg19().unwrap_err();
    assert!(matches!(err, WeightsError::EnvPathMissing { .. }));
    let msg = err.to_string();
    assert!(msg.contains(VGG19_ENV) && msg.contains("nst3d-locate") && msg.contains(FETCH_COMMAND), "{msg}");
    std::fs::remove_file(&file).ok();

    // Unset (or empty): the user cache dir, on Linux `$XDG_CACHE_HOME` or ~/.cache.
    std::env::set_var(VGG19_ENV, "");
    let cache = std::env::temp_dir().join(format!("nst3d-cache-{}", std::process::id()));
    std::env::set_var("XDG_CACHE_HOME", &cache);
    let expected = cache.join("nst3d/vgg_normalised.pth");
    assert_eq!(default_vgg19_path(), Some(expected.clone()));
    let err = locate_vgg19().unwrap_err();
    assert!(matches!(err, WeightsError::NotInstalled { .. }));
    assert!(err.to_string().contains(&format!("run `{FETCH_COMMAND}`")), "{err}");
    std::fs::create_dir_all(expected.parent().unwrap()).unwrap();
    std::fs::write(&expected, b"x").unwrap();
    assert_eq!(locate_vgg19().unwrap(), expected);
    std::fs::remove_dir_all(&cache).ok();
}
