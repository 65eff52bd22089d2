fn main() {
    println!("magcomp (in progress)");
}
