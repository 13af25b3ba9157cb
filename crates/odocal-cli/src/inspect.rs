//! `odocal inspect BAG`: what a ROS 2 bag (MCAP) holds, like `ros2 bag info`,
//! plus the manifest column names of each topic odocal reads.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

/// Arguments of `odocal inspect`.
#[derive(Args)]
pub struct InspectArgs {
    /// The bag: an `.mcap` file (or a bag directory holding one).
    bag: PathBuf,
}

/// Prints the bag's topics, types, counts and rates, then the columns a
/// manifest can take from each readable topic.
pub fn run(a: InspectArgs) -> Result<()> {
    let info = odocal::bag::inspect(&a.bag)?;
    print!("{info}");
    let readable: Vec<_> = info.topics.iter().filter_map(|t| Some((t, t.supported_type()?))).collect();
    if !readable.is_empty() {
        println!("Manifest columns (format = \"mcap\", topic = ...):");
        for (t, ty) in readable {
            println!("  {}: {}", t.topic, ty.columns().join(", "));
        }
    }
    Ok(())
}
