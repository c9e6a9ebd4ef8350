//! `nrc info`: what a scene holds.

use anyhow::Result;

use nrc_harness::options::SceneArgs;

/// Arguments of `nrc info`.
#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
}

/// Loads the scene and prints its summary: triangles, materials, lights, bounds, camera.
pub fn run(args: &InfoArgs) -> Result<()> {
    let scene = args.scene.load()?;
    println!("{}", scene.summary());
    Ok(())
}
