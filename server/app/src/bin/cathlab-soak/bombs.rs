//! The bomb files (a MetaImage declaring 10¹⁵ voxels, MetaImage and gzip NIfTI data that
//! inflate to 64 MiB) and the inline scenes naming them.

use std::path::Path;

use anyhow::{Context, Result, bail};

use crate::common::SCENE;

/// The bomb files and the inline scenes naming them.
pub(crate) struct Bombs {
    /// The directory they are in (a data root), as a refusal must not show it.
    pub(crate) dir: String,
    /// (file name, scene text).
    pub(crate) scenes: Vec<(&'static str, String)>,
}

/// `bytes` of zeros through `encoder`, a mebibyte at a time.
pub(crate) fn zeros_into<W: std::io::Write>(mut encoder: W, bytes: usize) -> std::io::Result<W> {
    let chunk = vec![0u8; 1 << 20];
    for _ in 0..bytes >> 20 {
        encoder.write_all(&chunk)?;
    }
    Ok(encoder)
}

/// A MetaImage (MET_UCHAR) with its data inline.
pub(crate) fn metaimage(dims: &str, compressed: bool, data: &[u8]) -> Vec<u8> {
    let mut out = format!(
        "ObjectType = Image\nNDims = 3\nDimSize = {dims}\nElementType = MET_UCHAR\n\
         CompressedData = {}\nElementDataFile = LOCAL\n",
        if compressed { "True" } else { "False" }
    )
    .into_bytes();
    out.extend_from_slice(data);
    out
}

/// A gzip NIfTI-1 declaring 1024³ bytes, whose data inflates to `bytes` of zeros.
pub(crate) fn nifti_gzip_bomb(bytes: usize) -> std::io::Result<Vec<u8>> {
    use std::io::Write as _;
    let mut header = vec![0u8; 352];
    header[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (o, v) in [
        (40, 3i16),
        (42, 1024),
        (44, 1024),
        (46, 1024),
        (70, 2),
        (72, 8),
    ] {
        header[o..o + 2].copy_from_slice(&v.to_le_bytes());
    }
    for o in [80, 84, 88] {
        header[o..o + 4].copy_from_slice(&1.0f32.to_le_bytes());
    }
    header[108..112].copy_from_slice(&352.0f32.to_le_bytes());
    header[344..348].copy_from_slice(b"n+1\0");
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    gz.write_all(&header)?;
    zeros_into(gz, bytes)?.finish()
}

/// Writes the bomb files into `dir` and makes the scenes naming them: the default scene
/// (read from `scenes`) with its `[ct]` a file.
pub(crate) fn write_bombs(dir: &Path, scenes: &Path) -> Result<Bombs> {
    std::fs::create_dir_all(dir)?;
    let zlib_zeros = zeros_into(
        flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best()),
        64 << 20,
    )?
    .finish()?;
    let files: [(&'static str, Vec<u8>); 3] = [
        // 150 bytes declaring 10¹⁵ voxels.
        (
            "tiny.mha",
            metaimage(
                "100000 100000 100000",
                true,
                &[0x78, 0x9c, 0x03, 0, 0, 0, 0, 1],
            ),
        ),
        // 64³ declared, 64 MiB inflated.
        ("lying.mha", metaimage("64 64 64", true, &zlib_zeros)),
        // 1024³ declared, 64 MiB inflated.
        ("bomb.nii.gz", nifti_gzip_bomb(64 << 20)?),
    ];
    let template = std::fs::read_to_string(scenes.join(format!("{SCENE}.toml")))
        .with_context(|| format!("the scene {SCENE} in {}", scenes.display()))?;
    let phantom = "[ct]\nkind = \"phantom\"\nspacing_mm = 2.0";
    if !template.contains(phantom) {
        bail!("the scene {SCENE} has no phantom [ct] for the bombs to replace");
    }
    let mut bombs = Bombs {
        dir: dir.display().to_string(),
        scenes: Vec::new(),
    };
    for (name, bytes) in files {
        let path = dir.join(name);
        std::fs::write(&path, bytes)?;
        let ct = format!(
            "[ct]\nkind = \"file\"\npath = {:?}",
            path.display().to_string()
        );
        bombs.scenes.push((name, template.replace(phantom, &ct)));
    }
    Ok(bombs)
}
