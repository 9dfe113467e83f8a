//! `view open FILE` (or `view FILE`): the interactive window.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::cmd::args::{BakedArgs, GpuArgs};
use crate::cmd::load::with_viewing;

/// Opens a window with a free camera and a movable light.
#[derive(Args, Debug)]
pub struct OpenArgs {
    #[command(flatten)]
    pub baked: BakedArgs,
    #[command(flatten)]
    pub gpu: GpuArgs,
    /// For scripts: after N frames save a screenshot of every view and close.
    #[arg(long, value_name = "N", hide = true)]
    pub exit_after_frames: Option<u32>,
    /// Where the P key saves screenshots.
    #[arg(long, value_name = "DIR", default_value = ".")]
    pub screenshot_dir: PathBuf,
    /// Move the light every frame, for timings (with --exit-after-frames: print the median).
    #[arg(long, hide = true)]
    pub moving_light: bool,
}

pub fn run(args: &OpenArgs) -> Result<()> {
    with_viewing(&args.baked, |mut v| {
        // Interactive: a light that moves is relit with last frame's correction where that
        // saves work, unless the command line says otherwise (`with_viewing` set it for
        // images).
        let pays = v.relighter.lag_pays();
        v.relighter.lagged_feedback = args.baked.relight.feedback_lag.lagged(true, pays);
        let moving_light = args.moving_light.then(|| v.path_radius());
        mlt_view::window::run(mlt_view::window::WindowSetup {
            title: format!("view {}", v.path.display()),
            scene: v.scene,
            ib: v.ib,
            bounds: v.bounds(),
            relighter: mlt_view::window::Relighting::Cpu(&mut v.relighter),
            gpu_relight: args.gpu.relight.choice(),
            half_splat: args.gpu.splat_bits == 16,
            camera: v.camera,
            light: v.light,
            shadow_res: args.gpu.shadow_res,
            gpu_flatten: args.gpu.flatten.choice(),
            exit_after_frames: args.exit_after_frames,
            screenshot_dir: args.screenshot_dir.clone(),
            moving_light,
        })
    })
}
