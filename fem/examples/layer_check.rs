//! Compare the FE gel (finite radius) with the analytical infinite layer, for a
//! rigid and an elastic (hemisphere) indenter.
use fem::{Body, Material, Mesh, TwoBodyContact};
use sim::physics::{Body as PBody, ContactPair, Layer, LayeredNormal, Profile};

fn main() {
    let (h, r2) = (5.0, 5.0);
    for nu in [0.3, 0.48] {
        let pair = ContactPair { elastomer: PBody::new(1.0, nu, f64::INFINITY), indenter: PBody::new(1e12, 0.3, r2) };
        let ana = LayeredNormal::with_profile(&pair, &Layer::bonded(h), 4.9, Profile::Sphere).unwrap();
        for radius in [60.0, 15.0] {
            let t = std::time::Instant::now();
            let gel = Body::new(Mesh::gel(radius, h, 0.05, 5.5, 1.5).unwrap(), Material { e_mpa: 1.0, nu }).unwrap();
            let c = TwoBodyContact::new(&gel, None, r2).unwrap();
            println!("setup {:.2?}", t.elapsed());
            for delta in [0.2, 0.6, 1.2] {
                let st = c.solve(delta).unwrap();
                let a = ana.solve(delta).unwrap();
                println!(
                    "rigid: nu {nu} gel r {radius:4}: delta {delta}: FE F {:.5} N a {:.3?} | layer F {:.5} a {:.3} | ratio {:.4}",
                    st.force_n,
                    st.contact_radius_mm,
                    a.force_n,
                    a.contact_radius_mm,
                    st.force_n / a.force_n
                );
            }
        }
    }
}
