#![forbid(unsafe_code)]

fn main() {
    eprintln!("rsmodbus-gateway: under construction (issue 40)");
    std::process::exit(1);
}
