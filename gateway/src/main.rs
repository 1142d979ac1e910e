//! rsmodbus-gateway(8): see `rsmodbus_gateway::run`.
#![forbid(unsafe_code)]

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    std::process::exit(rsmodbus_gateway::run::main(&args));
}
