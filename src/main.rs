fn main() {
    println!("easycalib");
}
