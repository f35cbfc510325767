//! Issue 27's end-to-end thermal check at the issue's full rate and lengths (18.9 Hz, 3 h ramp, 8 h orbit) or,
//! with `quick`, at a quarter of the rate (the demo's and the test's): `cargo run --release -p host-test --example
//! thermal_check [quick]`.

fn main() -> Result<(), host_test::thermal_check::ThermalCheckError> {
    use host_test::thermal_check::{ThermalCheckOptions, run};
    let quick = std::env::args().nth(1).as_deref() == Some("quick");
    let o = if quick {
        ThermalCheckOptions::QUICK
    } else {
        ThermalCheckOptions::ISSUE
    };
    print!("{}", run(&o)?.report());
    Ok(())
}
