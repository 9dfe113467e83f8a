//! `view probe FILE --probe IN.csv --probe-out OUT.csv`: the relit irradiance at given
//! surface points.

use anyhow::{bail, Context, Result};
use clap::Args;
use mlt_view::probe::{evaluate, parse_probes, to_csv};
use mlt_view::Relight;

use crate::cmd::args::{BakedArgs, ProbeArgs};
use crate::cmd::load::with_viewing;

/// Writes the irradiance at probe points.
#[derive(Args, Debug)]
pub struct ProbeCmdArgs {
    #[command(flatten)]
    pub baked: BakedArgs,
    #[command(flatten)]
    pub probes: ProbeArgs,
}

pub fn run(args: &ProbeCmdArgs) -> Result<()> {
    let (input, output) = (&args.probes.probe, &args.probes.probe_out);
    let text =
        std::fs::read_to_string(input).with_context(|| format!("reading {}", input.display()))?;
    let probes = parse_probes(input, &text)?;
    with_viewing(&args.baked, |mut v| {
        let frame = v.relighter.relight(&v.light);
        let values: Vec<_> = probes
            .iter()
            .map(|p| evaluate(v.ib, v.caster, &v.light, frame, v.sender_levels, p))
            .collect();
        if values.iter().flatten().flatten().any(|x| !x.is_finite()) {
            bail!("a probe's irradiance is not finite");
        }
        mlt_format::file::write_atomic(output, to_csv(&probes, &values).as_bytes())
            .with_context(|| format!("writing {}", output.display()))?;
        eprintln!("{} probes written to {}", probes.len(), output.display());
        Ok(())
    })
}
