//! What a built schedule actually runs: every system in execution order with its stage and the
//! components and resources it reads and writes, as bevy computed them from the system
//! parameters. The README's stage table is generated from this (and a test keeps it true).

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{InternedSystemSet, ScheduleBuildError};
use bevy_ecs::system::SystemAccess;

use super::TrainSet;

/// One system of a schedule, as it runs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SystemRow {
    /// The [`TrainSet`] the system belongs to (`None` for systems outside the tadgs stages).
    pub stage: Option<TrainSet>,
    /// Short type name of the system, e.g. `adam_step<Position>`.
    pub system: String,
    /// Components and resources read but not written, sorted by name.
    pub reads: Vec<String>,
    /// Components and resources written, sorted by name (`world` for exclusive systems).
    pub writes: Vec<String>,
}

const STAGES: [TrainSet; 8] = [
    TrainSet::SampleView,
    TrainSet::TimeWarp,
    TrainSet::Deform,
    TrainSet::Splat,
    TrainSet::Loss,
    TrainSet::Backward,
    TrainSet::Adam,
    TrainSet::Densify,
];

/// Builds `schedule` against `world` (registering what its systems use) and lists its systems
/// in the order the executor runs them.
pub fn describe(
    schedule: &mut Schedule,
    world: &mut World,
) -> Result<Vec<SystemRow>, ScheduleBuildError> {
    schedule.initialize(world)?;
    let stage_members: Vec<(TrainSet, Vec<_>)> = STAGES
        .iter()
        .filter_map(|&stage| {
            let set: InternedSystemSet = stage.intern();
            let members = schedule.graph().systems_in_set(set).ok()?;
            Some((stage, members.iter().copied().collect()))
        })
        .collect();
    let components = world.components();
    let name_of = |id| {
        components.get_name(id).map_or_else(
            || format!("{id:?}"),
            |name| short_type_name(&name.to_string()),
        )
    };
    let rows = schedule
        .systems_with_access()
        .expect("the schedule was initialised above")
        .map(|(key, system)| {
            let stage = stage_members
                .iter()
                .find(|(_, members)| members.contains(&key))
                .map(|(stage, _)| *stage);
            let (reads, writes) = match system.access() {
                SystemAccess::None => (Vec::new(), Vec::new()),
                SystemAccess::Exclusive => (Vec::new(), vec!["world".to_string()]),
                SystemAccess::Shared(access) => {
                    let combined = access.combined_access();
                    let writes: Vec<_> = combined
                        .writes()
                        .as_finite_set()
                        .map(|ids| ids.iter().collect())
                        .unwrap_or_default();
                    let reads: Vec<_> = combined
                        .reads()
                        .as_finite_set()
                        .map(|ids| ids.iter().filter(|id| !writes.contains(id)).collect())
                        .unwrap_or_default();
                    let names = |ids: Vec<_>| {
                        let mut names: Vec<String> = ids.into_iter().map(name_of).collect();
                        names.sort();
                        names.dedup();
                        names
                    };
                    (names(reads), names(writes))
                }
            };
            SystemRow {
                stage,
                system: short_type_name(&system.system().name().to_string()),
                reads,
                writes,
            }
        })
        .collect();
    Ok(rows)
}

/// The rows as a Markdown table: stage, system, reads, writes.
pub fn markdown_table(rows: &[SystemRow]) -> String {
    let mut table = String::from("| stage | system | reads | writes |\n|---|---|---|---|\n");
    for row in rows {
        let stage = row.stage.map_or("—".to_string(), |s| format!("`{s:?}`"));
        let list = |names: &[String]| {
            if names.is_empty() {
                "—".to_string()
            } else {
                names
                    .iter()
                    .map(|n| format!("`{n}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        };
        table += &format!(
            "| {stage} | `{}` | {} | {} |\n",
            row.system,
            list(&row.reads),
            list(&row.writes)
        );
    }
    table
}

/// `a::b::Grad<c::Position>` → `Grad<Position>`: drops every module path.
pub fn short_type_name(full: &str) -> String {
    let mut short = String::with_capacity(full.len());
    let mut segment_start = 0;
    let mut chars = full.chars().peekable();
    while let Some(c) = chars.next() {
        if c == ':' && chars.peek() == Some(&':') {
            chars.next();
            short.truncate(segment_start);
        } else {
            short.push(c);
            if !(c.is_alphanumeric() || c == '_') {
                segment_start = short.len();
            }
        }
    }
    short
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Module paths are dropped everywhere in a name, generic arguments included.
    #[test]
    fn short_names_drop_module_paths() {
        assert_eq!(
            short_type_name("tadgs::components::Grad<tadgs::components::Position>"),
            "Grad<Position>"
        );
        assert_eq!(
            short_type_name("tadgs::systems::adam::adam_step<a::B>"),
            "adam_step<B>"
        );
        assert_eq!(short_type_name("(a::B, c::D)"), "(B, D)");
        assert_eq!(short_type_name("Plain"), "Plain");
    }
}
