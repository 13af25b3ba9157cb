//! Lists a ROS 2 bag's topics like `ros2 bag info`, and with a topic also
//! the first rows of its table: what a manifest's MCAP stream can read
//! (feature `mcap`, on by default).
//!
//! ```sh
//! cargo run -p odocal --example bag_info -- data/psu-mapping-van-2024-07-11/drive.mcap
//! cargo run -p odocal --example bag_info -- BAG.mcap TOPIC [COLUMN ...]
//! ```

use odocal::io::bag::{self, TimeSource};
use std::path::Path;

fn main() -> Result<(), odocal::Error> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(path) = args.first() else {
        eprintln!("usage: bag_info BAG.mcap [TOPIC [COLUMN ...]]");
        std::process::exit(2);
    };
    let path = Path::new(path);
    match args.get(1) {
        None => print!("{}", bag::inspect(path)?),
        Some(topic) => {
            let cols: Vec<&str> = args[2..].iter().map(String::as_str).collect();
            let table = bag::read_topic(path, topic, &cols, TimeSource::HeaderStamp)?;
            println!("{}: {} rows", table.source, table.t_s.len());
            let names: Vec<&String> = table.columns.keys().collect();
            println!("t_s {}", names.iter().map(|n| n.as_str()).collect::<Vec<_>>().join(" "));
            for i in 0..table.t_s.len().min(5) {
                let row: Vec<String> = table.columns.values().map(|c| format!("{}", c[i])).collect();
                println!("{:.6} {}", table.t_s[i], row.join(" "));
            }
        }
    }
    Ok(())
}
