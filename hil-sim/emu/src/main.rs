fn main() -> anyhow::Result<()> {
    let elf = std::fs::read("target/thumbv7em-none-eabihf/release/drive-fw")?;
    let names: Vec<String> = std::env::args().skip(1).collect();
    for n in names {
        let o = drive_emu::scenarios::run(&n, &elf)?;
        println!("{}", drive_emu::scenarios::report(&[o], ""));
    }
    Ok(())
}
