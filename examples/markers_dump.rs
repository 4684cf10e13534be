use handcap::triangulate::marker::{find_markers, MarkerOptions};
fn main() {
    let dir = std::env::args().nth(1).unwrap();
    let truth = std::fs::read_to_string(std::env::args().nth(2).unwrap()).unwrap();
    let ext = std::env::var("HC_EXT").unwrap_or("jpg".into());
    println!("frame,camera,du,dv,u,v");
    let lines: Vec<Vec<String>> = truth
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    for cam in ["left", "right"] {
        let mine: Vec<&Vec<String>> = lines.iter().filter(|f| f[1] == cam).collect();
        for f in mine {
            let fi: usize = f[0].parse().unwrap();
            let (u, v): (f64, f64) = (f[7].parse().unwrap(), f[8].parse().unwrap());
            let image =
                handcap::image::decode(std::path::Path::new(&format!("{dir}/{cam}_{fi:05}.{ext}")))
                    .unwrap();
            let m = find_markers(&image, &MarkerOptions::default());
            if let Some(b) = m.blobs.iter().min_by(|a, b| {
                ((a.centre_px[0] - u).hypot(a.centre_px[1] - v))
                    .total_cmp(&(b.centre_px[0] - u).hypot(b.centre_px[1] - v))
            }) {
                println!(
                    "{fi},{cam},{:.4},{:.4},{u:.3},{v:.3}",
                    b.centre_px[0] - u,
                    b.centre_px[1] - v
                );
            }
        }
    }
}
