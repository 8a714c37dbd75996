//! Components read back from a world in entity order, for tests that compare two worlds
//! stepped alike.

use bevy_ecs::prelude::*;

/// Component `C` of every entity that has it, in entity order.
pub fn in_entity_order<C: Component + Copy>(world: &mut World) -> Vec<C> {
    let mut rows: Vec<(Entity, C)> = world
        .query::<(Entity, &C)>()
        .iter(world)
        .map(|(e, c)| (e, *c))
        .collect();
    rows.sort_by_key(|r| r.0);
    rows.into_iter().map(|r| r.1).collect()
}
