//! op3dsg-runtime's integration tests on real models: the text encoder and YOLOX through ONNX
//! Runtime. One test binary, a module per model.

mod text_encoder;
mod yolox;
