//! What `index build` takes from the simulator: the catalogue's names,
//! structures and attributes for its textile ids (T001.., U01..), the
//! simulated presses of `--sim` and the unseen textiles its coverage
//! report measures. Without the `sim` feature every textile is described
//! by its own name (`record --name`, else its id) and `--sim` is refused.

use anyhow::Result;
use telextiles_index::TextileRecord;
use telextiles_recording::Press;

/// The simulator catalogue an index is built against (`--catalogue`).
pub(crate) struct Catalogue {
    pub(crate) version: u32,
    #[cfg(feature = "sim")]
    cat: telextiles_sim::Catalogue,
}

impl Catalogue {
    #[cfg(feature = "sim")]
    pub(crate) fn open(version: u32) -> Result<Catalogue> {
        use anyhow::Context;
        let cat = telextiles_sim::Catalogue::version(version)
            .with_context(|| format!("no simulator catalogue {version}"))?;
        Ok(Catalogue {
            version: cat.version,
            cat,
        })
    }

    #[cfg(not(feature = "sim"))]
    pub(crate) fn open(version: u32) -> Result<Catalogue> {
        Ok(Catalogue { version })
    }

    /// A catalogue textile's name, book, structure and attributes into
    /// its record (a fabric of the user's own is left as it is).
    #[cfg(feature = "sim")]
    pub(crate) fn describe(&self, r: &mut TextileRecord) {
        use telextiles_sim::catalogue::{Attributes, Book};
        if let Some(t) = self.cat.get(&r.id) {
            r.name = t.name.clone();
            r.seen = t.book == Book::Training;
            r.structure = t.structure.label();
            r.attributes = Attributes::NAMES
                .iter()
                .zip(t.attributes.to_vec())
                .map(|(n, v)| (n.to_string(), v))
                .collect();
        }
    }

    #[cfg(not(feature = "sim"))]
    pub(crate) fn describe(&self, _r: &mut TextileRecord) {}
}

/// The simulated people and sensor units whose presses `--sim` renders.
#[cfg_attr(not(feature = "sim"), allow(dead_code))]
pub(crate) struct SimSet {
    pub(crate) people: u32,
    pub(crate) sensors: Vec<u32>,
}

/// Which of the catalogue's books.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Books {
    /// The training book (the textiles an index of `--sim` holds).
    Training,
    /// The unseen book (what the coverage report measures).
    Unseen,
    /// Both (`--include-unseen`).
    Both,
}

/// Renders every simulated press of `set` of the textiles of `books`
/// (every person on every sensor unit, jig, one press each) and hands
/// each to `each` with its textile id, in the catalogue's order; with
/// `progress`, shown as "simulated presses". Returns how many.
#[cfg(feature = "sim")]
pub(crate) fn for_each_press(
    cat: &Catalogue,
    set: &SimSet,
    books: Books,
    progress: bool,
    each: &mut dyn FnMut(&str, &Press) -> Result<()>,
) -> Result<usize> {
    let sim = telextiles_sim::Simulator::with_options(cat.version, 1)?;
    let protocol = sim_protocol(set, books)?;
    let progress = progress.then(|| {
        telextiles_progress::Progress::new(
            "index build",
            protocol.len(&cat.cat) as u64,
            "simulated presses",
        )
    });
    let mut presses = 0;
    for spec in protocol.specs(&cat.cat) {
        each(&spec.textile, &sim.render_press(&spec)?)?;
        presses += 1;
        if let Some(p) = &progress {
            p.inc(1);
        }
    }
    if let Some(p) = progress {
        p.finish();
    }
    Ok(presses)
}

#[cfg(not(feature = "sim"))]
pub(crate) fn for_each_press(
    _cat: &Catalogue,
    _set: &SimSet,
    _books: Books,
    _progress: bool,
    _each: &mut dyn FnMut(&str, &Press) -> Result<()>,
) -> Result<usize> {
    Err(crate::sim_off("`index build --sim`"))
}

/// The simulator's dataset protocol for `set` and `books`.
#[cfg(feature = "sim")]
pub(crate) fn sim_protocol(
    set: &SimSet,
    books: Books,
) -> Result<telextiles_sim::dataset::Protocol> {
    use telextiles_sim::catalogue::Book;
    if set.people == 0 || set.sensors.is_empty() {
        anyhow::bail!("--people and --sensors must name at least one simulated person and sensor");
    }
    let mut protocol = telextiles_sim::dataset::Protocol::paper();
    protocol.people = set.people;
    protocol.sensors = set.sensors.clone();
    protocol.jig = vec![true];
    match books {
        Books::Training => protocol.books = vec![Book::Training],
        Books::Unseen => protocol.books = vec![Book::Unseen],
        Books::Both => {}
    }
    Ok(protocol)
}
