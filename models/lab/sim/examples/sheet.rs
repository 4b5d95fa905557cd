//! Write the contact sheet to the path given (default docs/contact-sheet.png)
//! and print the tile descriptions. `telextilesd sim contact-sheet` does the
//! same from the daemon's command line.
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "docs/contact-sheet.png".into());
    let sim = telextiles_sim::Simulator::new()?;
    let (img, tiles) = telextiles_sim::sheet::contact_sheet(&sim)?;
    img.save(&out)?;
    for (i, t) in tiles.iter().enumerate() {
        println!("{i:2} {}: {}", t.label, t.description);
    }
    Ok(())
}
