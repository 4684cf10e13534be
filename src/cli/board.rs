//! The board flags `calibrate`, `synth` and `capture --calib` share, and `handcap board`: a
//! printable board at true size.

use std::path::PathBuf;

use crate::calib::{file, print, Dictionary, Layout, PartialBoard};

/// The printed board, as flags.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct BoardArgs {
    /// The board: COLSxROWS inner corners of a chessboard (e.g. 9x6), or charuco:SXxSY squares
    /// of a ChArUco board (e.g. charuco:10x7; OpenCV's convention) [default: the folder's
    /// board.yml, else calib/board.yml's 9x6]
    #[arg(long)]
    pub board: Option<Layout>,
    /// The printed square's side, mm [default: board.yml's]
    #[arg(long, value_parser = super::finite)]
    pub square_mm: Option<f64>,
    /// A ChArUco board's printed marker side, mm (smaller than the square)
    #[arg(long, value_parser = super::finite)]
    pub marker_mm: Option<f64>,
    /// A ChArUco board's ArUco dictionary, by OpenCV's name [default: DICT_5X5_100]
    #[arg(long)]
    pub dictionary: Option<Dictionary>,
}

impl BoardArgs {
    pub fn flags(&self) -> PartialBoard {
        PartialBoard {
            layout: self.board,
            square_mm: self.square_mm,
            marker_mm: self.marker_mm,
            dictionary: self.dictionary,
        }
    }

    /// Whether any board flag was given.
    pub fn any(&self) -> bool {
        self.flags() != PartialBoard::default()
    }
}

/// `handcap board`: writes a board to print (SVG at true size) and its `board.yml`.
#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    board: BoardArgs,
    /// The SVG to write; the board's description is written beside it as the same name .yml
    /// (board.yml by default)
    #[arg(long, default_value = "board.svg")]
    out: PathBuf,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let board = match a.board.flags().over(&file::default_board()) {
        Ok(b) => b,
        Err(e) => super::usage!("{e}"),
    };
    board.check()?;
    let svg = print::svg(&board)?;
    let yaml = a.out.with_extension("yml");
    for (path, text) in [(&a.out, svg.as_str()), (&yaml, &file::board_yaml(&board))] {
        crate::fsio::write_bytes(path, text.as_bytes())
            .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))?;
    }
    let [w, h] = print::page_mm(&board);
    let sizes = board.pattern.kind().measured();
    println!(
        "wrote {} ({board}; {w:.0} × {h:.0} mm) and {}: print at 100 % (no fit to page), measure a square, correct {sizes} if the printer scaled them, and put the file in the calibration folder as board.yml",
        a.out.display(),
        yaml.display()
    );
    Ok(())
}
