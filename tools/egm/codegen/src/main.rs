fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (proto_dir, out_dir) = (&args[1], &args[2]);
    let fds = protox::compile(["egm.proto"], [proto_dir]).expect("egm.proto compiles");
    let mut cfg = prost_build::Config::new();
    cfg.out_dir(out_dir);
    cfg.compile_fds(fds).expect("prost-build generates");
}
