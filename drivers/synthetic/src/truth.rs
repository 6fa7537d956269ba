//! The synthetic world's functional ground truth: what each interactive part (and each object
//! that acts on another) does and which affordances it has, and the rooms where a real home
//! differs from the usual answer.
//!
//! # Where it comes from
//!
//! This table is authored for the synthetic rooms from the benchmark's own definitions, never
//! from the knowledge base the runtime reasons with (`profiles/knowledge/`, which this crate
//! does not read and the runtime never reads this one):
//!
//! - the 11 canonical functional relations and their frequencies in UniGraph3D
//!   (`../shared/data/reference/unigraph3d_functional_relation_labels.json`, README table);
//! - the 9 affordance labels (`unigraph3d_affordance_labels.json`) with the paper's definitions
//!   and examples (OP3DSG paper, supplementary "Affordance Annotation": *rotate* — a knob or
//!   dial, "thermostat knob, stove burner dial"; *key press* — "remote control keypad";
//!   *tip push* — "light switch, elevator button"; *hook pull* — "refrigerator handle, cabinet
//!   handle"; *pinch pull* — "drawer knob, cabinet knob"; *hook turn* — "door handle, faucet
//!   lever"; *foot push* — "trash can pedal"; *plug in* / *unplug* — "power outlet");
//! - the benchmark's node vocabularies (`unigraph3d_*_node_labels.json`: "nightstand drawer",
//!   "television stand / cabinet", "switch panel / electric outlet", ...) and the object → part
//!   table of the paper's code (`capa3dsg_object_part_knowledge.json`: radiator → valve, ...);
//! - the geometry the catalog gives each part (a lever, a round knob, a wall plate).
//!
//! Every entry states its reason. Where this table and the knowledge base give the same answer
//! they agree because both describe the same homes, not because one was copied from the other;
//! `op3dsg bench quality` reports how often they agree.
//!
//! # Rooms that differ from the usual answer
//!
//! [`DEVIATIONS`] lists cases a real room has and a per-category table gets wrong (a knob that
//! opens a door instead of adjusting a setting, a switch whose light is in the next room, an
//! outlet with nothing plugged in, a remote far from its TV). Each has a probability; the
//! catalog draws them from a random stream of their own, seeded by the room and seed (so the
//! rest of a room's layout is the same whether or not a case is drawn), and records which
//! instances they touched ([`crate::Scene::deviations`]).

/// Canonical functional relations (the benchmark's 11 phrases).
pub mod relation {
    /// Pull to open or close.
    pub const PULL: &str = "pull to open or close";
    /// Control the water flow.
    pub const WATER: &str = "control the water flow";
    /// Rotate to adjust the setting or temperature.
    pub const ADJUST: &str = "rotate to adjust the setting or temperature";
    /// Press to start and operate.
    pub const PRESS_START: &str = "press to start and operate";
    /// Turn on or turn off.
    pub const SWITCH: &str = "turn on or turn off";
    /// Remote to control.
    pub const REMOTE: &str = "remote to control";
    /// Press to flush.
    pub const FLUSH: &str = "press to flush";
    /// Provide power.
    pub const POWER: &str = "provide power";
    /// Push or press to open.
    pub const PUSH_OPEN: &str = "push or press to open";
    /// Operate or adjust the flow or setting.
    pub const FLOW_SETTING: &str = "operate or adjust the flow or setting";
    /// Rotate to open or close.
    pub const ROTATE_OPEN: &str = "rotate to open or close";
}

use relation::{ADJUST, FLOW_SETTING, FLUSH, POWER, PRESS_START, PULL, PUSH_OPEN, REMOTE, ROTATE_OPEN, SWITCH, WATER};

/// What one kind of part does, on one kind of object.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PartTruth {
    /// The part's label as the catalog writes it.
    pub part: &'static str,
    /// The label of the object it is part of; `""` for a part fixed to the wall (switch and
    /// outlet plates), which acts on a separate object.
    pub on: &'static str,
    /// Its functional relation (towards its own object, or for wall plates towards the object
    /// the catalog wires it to); `None`: it acts on nothing in the room.
    pub relation: Option<&'static str>,
    /// Its affordances (the benchmark's labels).
    pub affordances: &'static [&'static str],
    /// Why (definitions, geometry).
    pub reason: &'static str,
}

/// What an object that acts on another object does (a remote control).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ObjectTruth {
    /// The object's label.
    pub object: &'static str,
    /// Its functional relation towards the object it acts on.
    pub relation: &'static str,
    /// Its affordances.
    pub affordances: &'static [&'static str],
    /// Why.
    pub reason: &'static str,
}

const fn part(
    part: &'static str,
    on: &'static str,
    relation: &'static str,
    affordances: &'static [&'static str],
    reason: &'static str,
) -> PartTruth {
    PartTruth { part, on, relation: Some(relation), affordances, reason }
}

/// Every part the catalog builds, by (part label, object label).
pub const PARTS: &[PartTruth] = &[
    // ---- storage: doors and drawers that are pulled open ------------------------------------
    part(
        "cabinet handle",
        "cabinet",
        PULL,
        &["hook_pull"],
        "a bar handle on a cabinet door: the paper's hook-pull example is the cabinet handle; the door swings open when \
         pulled, 'pull to open or close' (the benchmark's most frequent relation, 111 / 109 edges)",
    ),
    part(
        "cabinet knob",
        "cabinet",
        PULL,
        &["pinch_pull"],
        "a fixed round knob on a cabinet door: pinch pull's examples are 'drawer knob, cabinet knob', and the paper's \
         qualitative results show cabinet knobs as 'pull to open'; it does not turn (a knob that turns a latch is the \
         turn-latch case in DEVIATIONS)",
    ),
    part(
        "drawer handle",
        "drawer",
        PULL,
        &["hook_pull"],
        "a bar handle on a drawer front: hooked by the fingers and pulled, the drawer slides out",
    ),
    part(
        "drawer knob",
        "drawer",
        PULL,
        &["pinch_pull"],
        "a round knob on a drawer front: pinch pull's first example is the drawer knob",
    ),
    part(
        "drawer handle",
        "dresser",
        PULL,
        &["hook_pull"],
        "a dresser's drawers have bar handles like any drawer ('dresser / chest of drawers' in the benchmark's labels)",
    ),
    part(
        "drawer knob",
        "dresser",
        PULL,
        &["pinch_pull"],
        "a dresser's drawer knobs are pinched and pulled like any drawer's",
    ),
    part(
        "drawer knob",
        "nightstand",
        PULL,
        &["pinch_pull"],
        "the nightstand's drawer knob ('nightstand drawer' in SceneFun3D's labels): pinched and pulled",
    ),
    part(
        "drawer handle",
        "tv stand",
        PULL,
        &["hook_pull"],
        "drawers of a TV stand ('television stand / cabinet' in SceneFun3D's labels): bar handles pulled",
    ),
    part(
        "wardrobe handle",
        "wardrobe",
        PULL,
        &["hook_pull"],
        "vertical bar handles on wardrobe doors: hooked and pulled, the doors swing open",
    ),
    part(
        "fridge handle",
        "fridge",
        PULL,
        &["hook_pull"],
        "hook pull's first example is the refrigerator handle; the fridge door is pulled open",
    ),
    part(
        "oven handle",
        "stove",
        PULL,
        &["hook_pull"],
        "the bar across the oven door: hooked and pulled down, the door opens",
    ),
    // ---- settings ---------------------------------------------------------------------------
    part(
        "stove knob",
        "stove",
        ADJUST,
        &["rotate"],
        "rotate's example is the stove burner dial; a burner knob sets the heat, 'rotate to adjust the setting or \
         temperature' (40 FunGraph3D edges)",
    ),
    part(
        "radiator valve",
        "radiator",
        FLOW_SETTING,
        &["rotate"],
        "the paper's object-part table lists radiator → valve; a manual valve turns to let more or less hot water \
         through the radiator, 'operate or adjust the flow or setting' (FunGraph3D's one edge of it)",
    ),
    part("knob", "control panel", ADJUST, &["rotate"], "the colour panel's knobs are dials: rotated to set a value"),
    // ---- doors and windows that are turned open ---------------------------------------------
    part(
        "door handle",
        "door",
        ROTATE_OPEN,
        &["hook_turn"],
        "hook turn's first example is the door handle: the lever is turned to unlatch the door, 'rotate to open or \
         close'",
    ),
    part(
        "window handle",
        "window",
        ROTATE_OPEN,
        &["hook_turn"],
        "a window's lever handle is turned a quarter turn to open the casement, like a door handle",
    ),
    // ---- water ------------------------------------------------------------------------------
    part(
        "faucet",
        "sink",
        WATER,
        &["hook_turn"],
        "the sink's faucet is a single-lever mixer on a post (hook turn's example is the faucet lever): the lever is \
         turned to run and mix the water, 'control the water flow'",
    ),
    part(
        "faucet",
        "bathtub",
        WATER,
        &["rotate"],
        "the bathtub's faucet is a round mixer knob on the wall above a spout: rotated to run the water (rotate: 'a \
         knob or dial')",
    ),
    part(
        "flush button",
        "toilet",
        FLUSH,
        &["tip_push"],
        "a push plate on the cistern: pressed with a fingertip, 'press to flush'",
    ),
    // ---- buttons, levers, pedals ------------------------------------------------------------
    part(
        "microwave button",
        "microwave",
        PRESS_START,
        &["tip_push"],
        "a push button on the control strip starts the microwave (tip push: 'elevator button'), 'press to start and \
         operate'",
    ),
    part(
        "toaster lever",
        "toaster",
        PRESS_START,
        &["tip_push"],
        "the toaster's lever is pushed down with a fingertip to lower the bread and start toasting",
    ),
    part("power button", "game console", PRESS_START, &["tip_push"], "the console's power button: pressed to start it"),
    part(
        "push button",
        "control panel",
        PRESS_START,
        &["tip_push"],
        "the colour panel's push buttons: pressed to start or operate",
    ),
    part(
        "pedal",
        "trash can",
        PUSH_OPEN,
        &["foot_push"],
        "foot push's example is the trash can pedal: pressed by the foot, the lid opens, 'push or press to open'",
    ),
    // ---- light and power --------------------------------------------------------------------
    part(
        "lamp switch",
        "lamp",
        SWITCH,
        &["tip_push"],
        "a push switch on the lamp's base or cord switches its own lamp: 'turn on or turn off', tip push like a \
         light switch",
    ),
    part(
        "lamp switch",
        "floor lamp",
        SWITCH,
        &["tip_push"],
        "a push switch on the floor lamp's stem switches that lamp",
    ),
    part(
        "light switch",
        "",
        SWITCH,
        &["tip_push"],
        "a wall switch plate (tip push's example is the light switch) turns on or off the light it is wired to, which \
         the catalog names; not necessarily the nearest light",
    ),
    part(
        "power outlet",
        "",
        POWER,
        &["plug_in", "unplug"],
        "a wall outlet with an appliance plugged in provides it power; with a plug in it both plug in and unplug are \
         feasible (both definitions name the power outlet)",
    ),
    part(
        "power outlet",
        "power strip",
        POWER,
        &["plug_in", "unplug"],
        "a socket of a power strip with a device plugged in provides it power (unplug's example: 'extension cord \
         socket')",
    ),
];

/// Objects that act on another object.
pub const OBJECTS: &[ObjectTruth] = &[ObjectTruth {
    object: "remote control",
    relation: REMOTE,
    affordances: &["key_press"],
    reason: "key press's first example is the remote control keypad; it controls the TV it belongs to, 'remote to \
             control' (13 SceneFun3D edges)",
}];

/// The truth of part `part` on object `on` (`""` for wall plates).
pub fn part_truth(part: &str, on: &str) -> Option<&'static PartTruth> {
    PARTS.iter().find(|t| t.part == part && t.on == on)
}

/// The truth of an object that acts on another one.
pub fn object_truth(object: &str) -> Option<&'static ObjectTruth> {
    OBJECTS.iter().find(|t| t.object == object)
}

/// One way a real room differs from the usual answer, with the probability the catalog draws
/// it with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deviation {
    /// Short name (reports, [`crate::Scene::deviations`]).
    pub name: &'static str,
    /// Probability per occasion ([`Deviation::occasion`]).
    pub probability: f64,
    /// Where it is drawn.
    pub occasion: &'static str,
    /// The part's truth in this case (`None`: the part's truth is the usual one, only where it
    /// is or what it acts on differs).
    pub truth: Option<PartTruth>,
    /// What the room has and why it is real.
    pub reason: &'static str,
}

/// A cabinet knob that turns a latch.
pub const TURN_LATCH_KNOB: Deviation = Deviation {
    name: "turn-latch cabinet knob",
    probability: 0.3,
    occasion: "each cabinet that has knobs",
    truth: Some(PartTruth {
        part: "cabinet knob",
        on: "cabinet",
        relation: Some(ROTATE_OPEN),
        affordances: &["rotate", "pinch_pull"],
        reason: "a turn knob works a latch: it is rotated to free the door, then pinched and pulled",
    }),
    reason: "older and bathroom cabinets often close with a turn-knob latch: the knob opens the cabinet by rotation \
             ('rotate to open or close', 14-16 benchmark edges) instead of being pulled",
};

/// An oven door opened by a knob.
pub const OVEN_DOOR_KNOB: Deviation = Deviation {
    name: "oven door knob",
    probability: 0.35,
    occasion: "each stove",
    truth: Some(PartTruth {
        part: "oven knob",
        on: "stove",
        relation: Some(PULL),
        affordances: &["pinch_pull"],
        reason: "a knob on the oven door, pinched and pulled to open it",
    }),
    reason: "some cookers have a knob instead of a bar on the oven door: a knob on a stove that opens a door rather \
             than adjusting a setting; a per-category table that maps 'knob on a stove' to a burner dial gets it wrong",
};

/// A switch wired to a light outside the room.
pub const SWITCH_FOR_NEXT_ROOM: Deviation = Deviation {
    name: "switch for the next room",
    probability: 0.4,
    occasion: "each door's switch plate",
    truth: Some(PartTruth {
        part: "light switch",
        on: "",
        relation: None,
        affordances: &["tip_push"],
        reason: "it switches the hall light on the other side of the wall: nothing in this room",
    }),
    reason: "a switch beside a door often serves the hall or the next room; its light is not in the scene, so it has \
             no functional edge here, while the nearest light is right there",
};

/// A door switch that controls a lamp across the room.
pub const SWITCH_FOR_FAR_LAMP: Deviation = Deviation {
    name: "switch for a far lamp",
    probability: 0.5,
    occasion: "each living room with a floor lamp",
    truth: None,
    reason: "a second switch at the door works a switched outlet across the room into which the floor lamp is \
             plugged: it controls that lamp across the room, not the ceiling light",
};

/// An outlet with nothing plugged in.
pub const EMPTY_OUTLET: Deviation = Deviation {
    name: "empty outlet",
    probability: 0.5,
    occasion: "each room (an outlet by the door, low on the wall)",
    truth: Some(PartTruth {
        part: "power outlet",
        on: "",
        relation: None,
        affordances: &["plug_in"],
        reason: "nothing is plugged in: it powers nothing, and only plug in is feasible (unplug needs a plug)",
    }),
    reason: "most rooms have outlets nobody uses; one near an appliance is not necessarily the one it is plugged into",
};

/// A remote control left far from its TV.
pub const REMOTE_AWAY_FROM_TV: Deviation = Deviation {
    name: "remote away from its TV",
    probability: 0.5,
    occasion: "each living room with a sideboard",
    truth: None,
    reason: "remotes get left anywhere: this one lies on the far end of the sideboard, about 3 m from the TV and far \
             outside any neighbourhood of it; it still controls the TV",
};

/// Every deviation the catalog can draw.
pub const DEVIATIONS: [&Deviation; 6] = [
    &TURN_LATCH_KNOB,
    &OVEN_DOOR_KNOB,
    &SWITCH_FOR_NEXT_ROOM,
    &SWITCH_FOR_FAR_LAMP,
    &EMPTY_OUTLET,
    &REMOTE_AWAY_FROM_TV,
];

/// A deviation drawn in a scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SceneDeviation {
    /// [`Deviation::name`].
    pub name: &'static str,
    /// The instance it concerns.
    pub instance: u16,
}

#[cfg(test)]
mod tests {
    use super::*;

    const AFFORDANCES: [&str; 9] =
        ["rotate", "key_press", "tip_push", "hook_pull", "pinch_pull", "hook_turn", "foot_push", "plug_in", "unplug"];

    #[test]
    fn entries_use_the_benchmark_labels_and_say_why() {
        let truths = PARTS.iter().chain(DEVIATIONS.iter().filter_map(|d| d.truth.as_ref()));
        for t in truths {
            if let Some(r) = t.relation {
                assert!(crate::FUNCTIONAL_RELATIONS.contains(&r), "{}: {r}", t.part);
            }
            assert!(!t.affordances.is_empty(), "{}", t.part);
            assert!(t.affordances.iter().all(|a| AFFORDANCES.contains(a)), "{}", t.part);
            assert!(t.reason.len() > 20, "{} on {}", t.part, t.on);
        }
        for (i, t) in PARTS.iter().enumerate() {
            assert!(!PARTS[i + 1..].iter().any(|o| o.part == t.part && o.on == t.on), "{} on {} twice", t.part, t.on);
        }
        for d in DEVIATIONS {
            assert!(d.probability > 0.0 && d.probability < 1.0, "{}", d.name);
            assert!(d.reason.len() > 20, "{}", d.name);
        }
    }
}
