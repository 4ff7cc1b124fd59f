//! `cathlab-xray`: renders a scene file to a PNG for eyes-on checks.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use cathlab_xray::scene::SceneSpec;
use cathlab_xray::{CpuRenderer, GpuRenderer, Renderer};
use clap::{Parser, Subcommand, ValueEnum};

#[derive(Parser)]
#[command(
    name = "cathlab-xray",
    about = "Synthetic fluoroscopy from the command line"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, ValueEnum)]
enum Backend {
    Cpu,
    Gpu,
}

#[derive(Subcommand)]
enum Command {
    /// Renders one frame of a scene (YAML) to a greyscale PNG.
    Render {
        /// The scene file.
        #[arg(long)]
        scene: PathBuf,
        /// The PNG to write.
        #[arg(long)]
        out: PathBuf,
        /// Which renderer.
        #[arg(long, value_enum, default_value = "cpu")]
        renderer: Backend,
        /// Bits per pixel of the PNG (8 or 16).
        #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u8).range(8..=16))]
        bits: u8,
    },
}

fn main() -> ExitCode {
    let Command::Render {
        scene,
        out,
        renderer,
        bits,
    } = Cli::parse().command;
    match run(&scene, &out, renderer, bits) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cathlab-xray: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(
    scene: &std::path::Path,
    out: &std::path::Path,
    backend: Backend,
    bits: u8,
) -> Result<(), Box<dyn std::error::Error>> {
    if bits != 8 && bits != 16 {
        return Err(format!("--bits must be 8 or 16, got {bits}").into());
    }
    let started = Instant::now();
    let loaded = SceneSpec::read(scene)?.load(scene)?;
    let loaded_s = started.elapsed().as_secs_f64();
    let renderer: Box<dyn Renderer> = match backend {
        Backend::Cpu => Box::new(CpuRenderer::default()),
        Backend::Gpu => Box::new(GpuRenderer::new()?),
    };
    let name = renderer.name();
    let started = Instant::now();
    let frame = loaded.render(renderer)?;
    let (w, h) = (frame.width, frame.height);
    if bits == 16 {
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, frame.to_16bit())
            .ok_or("image size mismatch")?
            .save(out)?;
    } else {
        image::GrayImage::from_raw(w, h, frame.to_8bit())
            .ok_or("image size mismatch")?
            .save(out)?;
    }
    println!(
        "{}: {w}×{h} {:?} frame on {name}, scene loaded in {loaded_s:.2} s, rendered in {:.2} s; \
         volume {:?} voxels, {} layer pieces",
        out.display(),
        frame.mode,
        started.elapsed().as_secs_f64(),
        loaded.volume.dims,
        loaded.with_contrast.pieces().len(),
    );
    Ok(())
}
