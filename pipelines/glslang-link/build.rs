//! Debian/Ubuntu ship `libshaderc_combined.a` without glslang and SPIRV-Tools
//! inside it; shaderc-sys links that archive statically, so the build script
//! of tgs-pipelines also needs these archives, in this order.

use std::path::Path;

const LIBS: &[&str] =
    &["SPIRV", "glslang", "MachineIndependent", "GenericCodeGen", "OSDependent", "OGLCompiler", "glslang-default-resource-limits", "SPIRV-Tools-opt", "SPIRV-Tools"];

fn main() {
    println!("cargo:rerun-if-env-changed=SHADERC_LIB_DIR");
    let arch = std::env::var("CARGO_CFG_TARGET_ARCH").unwrap_or_default();
    let mut dirs: Vec<String> = Vec::new();
    if let Ok(d) = std::env::var("SHADERC_LIB_DIR") {
        dirs.push(d);
    }
    dirs.push(format!("/usr/lib/{arch}-linux-gnu"));
    dirs.push("/usr/lib".into());
    dirs.push("/usr/local/lib".into());
    let dir = dirs.iter().find(|d| Path::new(d).join("libglslang.a").exists());
    match dir {
        Some(d) => {
            println!("cargo:rustc-link-search=native={d}");
            for l in LIBS {
                if Path::new(d).join(format!("lib{l}.a")).exists() {
                    println!("cargo:rustc-link-lib=static={l}");
                }
            }
            println!("cargo:rustc-link-lib=dylib=stdc++");
        }
        None => println!("cargo:warning=static glslang not found (looked in {dirs:?}); install glslang-dev spirv-tools (scripts/setup.sh)"),
    }
}
