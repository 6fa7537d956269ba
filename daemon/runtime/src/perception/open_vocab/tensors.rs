//! The tensors a model of each family must have, checked when the detector loads.

use super::{Family, OpenVocabConfig, OutputNames, TextInput, TextInputKind};
use crate::onnx::contract::{Dim, FLOAT, INDEX, INT64, TensorSpec};

/// The tensors `config`'s model must have: `(inputs, outputs, what)`, `what` naming the
/// contract for messages.
pub(super) fn contract_tensors(
    config: &OpenVocabConfig,
    text: &TextInput,
    outputs: &OutputNames,
    text_dim: usize,
) -> (Vec<TensorSpec>, Vec<TensorSpec>, String) {
    const KEY: &str = "detector.open_vocab";
    let family = config.family;
    // Family layouts are named by the family key, generic ones by the key of each name.
    let key = |field: &str| match family {
        Family::Generic => format!("{KEY}.{field}"),
        _ => format!("{KEY}.family = \"{}\"", family.as_str()),
    };
    let image =
        Some(vec![Dim::Is(1), Dim::Is(3), Dim::Is(config.input.height.into()), Dim::Is(config.input.width.into())]);
    let mut inputs = vec![TensorSpec::new(&config.input.name, &format!("{KEY}.input.name"), FLOAT, image)];
    match text.kind {
        TextInputKind::None => {}
        TextInputKind::Embeddings => {
            let mut dims = vec![Dim::Any("P"), Dim::Is(text_dim as i64)];
            if text.batch_axis {
                dims.insert(0, Dim::Is(1));
            }
            inputs.push(TensorSpec::new(&text.name, &key("text.name"), FLOAT, Some(dims)));
        }
        TextInputKind::Tokens => {
            let tokens = || Some(vec![Dim::Any("P"), Dim::Any("L")]);
            inputs.push(TensorSpec::new(&text.name, &key("text.name"), INT64, tokens()));
            if let Some(mask) = &text.attention_mask {
                inputs.push(TensorSpec::new(mask, &key("text.attention_mask"), INT64, tokens()));
            }
        }
    }
    let (boxes, scores) = match family {
        // Generic outputs may carry a batch axis or not; their shapes are checked when run.
        Family::Generic => (None, None),
        _ => (Some(vec![Dim::Is(1), Dim::Any("A"), Dim::Is(4)]), Some(vec![Dim::Is(1), Dim::Any("A"), Dim::Any("P")])),
    };
    let mut outs = vec![
        TensorSpec::new(&outputs.boxes, &key("outputs.boxes"), FLOAT, boxes),
        TensorSpec::new(&outputs.scores, &key("outputs.scores"), FLOAT, scores),
    ];
    for (field, name, dtypes) in [
        ("outputs.prompt_index", &outputs.prompt_index, INDEX),
        ("outputs.masks", &outputs.masks, FLOAT),
        ("outputs.region_embeddings", &outputs.region_embeddings, FLOAT),
    ] {
        if let Some(name) = name {
            outs.push(TensorSpec::new(name, &key(field), dtypes, None));
        }
    }
    let what = match family {
        Family::Generic => format!("the profile's contract ({KEY})"),
        _ => format!("the {} family's export layout ({KEY}.family)", family.as_str()),
    };
    (inputs, outs, what)
}
