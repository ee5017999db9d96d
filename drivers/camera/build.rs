//! `firewire` feature: link libdc1394 through pkg-config and compile the C layout probe.
fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    #[cfg(feature = "firewire")]
    firewire();
}

#[cfg(feature = "firewire")]
fn firewire() {
    println!("cargo:rerun-if-changed=src/firewire/layout.c");
    let lib = pkg_config::Config::new()
        .atleast_version("2.2")
        .probe("libdc1394-2")
        .unwrap_or_else(|e| {
            panic!(
                "the `firewire` feature needs libdc1394 (Debian: apt-get install libdc1394-dev): {e}"
            )
        });
    let mut build = cc::Build::new();
    build.file("src/firewire/layout.c");
    for dir in &lib.include_paths {
        build.include(dir);
    }
    build.compile("csmetro_dc1394_layout");
}
