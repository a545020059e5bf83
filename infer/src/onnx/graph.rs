//! A small builder of ONNX graphs: named initializers, single-output nodes with fresh names, and
//! the layers of lfit's network (Linear as `Gemm`, LayerNorm as `LayerNormalization`, BatchNorm
//! in inference mode as `BatchNormalization`) read from Burn modules.

use burn::nn::{BatchNorm, LayerNorm, Linear};
use burn::tensor::Tensor;

use super::proto::{
    AttributeProto, GraphProto, NodeProto, TensorProto, TensorShapeProto, TypeProto,
    ValueInfoProto, attribute_type, tensor_shape_proto, type_proto,
};
use super::{FLOAT, INT64, OnnxError};

/// Host values of a Burn tensor, row-major ([`lfit_nn::host::values`], as an export error).
pub fn values<const D: usize>(t: Tensor<D>) -> Result<Vec<f32>, OnnxError> {
    lfit_nn::host::values(t).map_err(|e| OnnxError::Export(e.to_string()))
}

pub use lfit_nn::host::layer_norm_epsilon;

/// A graph under construction.
#[derive(Debug, Default)]
pub struct Graph {
    pub proto: GraphProto,
    counter: usize,
}

/// Shape of a graph input or output: a symbolic batch and a fixed width.
fn batch_by(width: usize) -> TypeProto {
    use tensor_shape_proto::dimension::Value;
    let dim = |v: Value| tensor_shape_proto::Dimension { value: Some(v) };
    TypeProto {
        value: Some(type_proto::Value::TensorType(type_proto::Tensor {
            elem_type: FLOAT,
            shape: Some(TensorShapeProto {
                dim: vec![
                    dim(Value::DimParam("batch".into())),
                    dim(Value::DimValue(width as i64)),
                ],
            }),
        })),
    }
}

pub fn attr_int(name: &str, i: i64) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: attribute_type::INT,
        i: Some(i),
        ..Default::default()
    }
}

pub fn attr_float(name: &str, f: f32) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: attribute_type::FLOAT,
        f: Some(f),
        ..Default::default()
    }
}

impl Graph {
    pub fn new(name: &str) -> Self {
        Self {
            proto: GraphProto {
                name: name.into(),
                ..Default::default()
            },
            counter: 0,
        }
    }

    /// Declares a `[batch, width]` float input.
    pub fn input(&mut self, name: &str, width: usize, doc: &str) -> String {
        self.proto.input.push(ValueInfoProto {
            name: name.into(),
            r#type: Some(batch_by(width)),
            doc_string: doc.into(),
        });
        name.into()
    }

    /// Makes `value` a `[batch, width]` float output called `name`.
    pub fn output(&mut self, value: &str, name: &str, width: usize, doc: &str) {
        let value = if value == name {
            value.to_string()
        } else {
            self.node_named("Identity", &[value], vec![], name)
        };
        self.proto.output.push(ValueInfoProto {
            name: value,
            r#type: Some(batch_by(width)),
            doc_string: doc.into(),
        });
    }

    /// A float initializer.
    pub fn init(&mut self, prefix: &str, dims: &[usize], data: &[f32]) -> String {
        debug_assert_eq!(dims.iter().product::<usize>(), data.len());
        self.counter += 1;
        let name = format!("{prefix}#{}", self.counter);
        self.proto.initializer.push(TensorProto {
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: FLOAT,
            name: name.clone(),
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        });
        name
    }

    /// An int64 initializer.
    pub fn init_i64(&mut self, prefix: &str, data: &[i64]) -> String {
        self.counter += 1;
        let name = format!("{prefix}#{}", self.counter);
        self.proto.initializer.push(TensorProto {
            dims: vec![data.len() as i64],
            data_type: INT64,
            name: name.clone(),
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        });
        name
    }

    /// A scalar float constant (broadcast by the elementwise ops).
    pub fn scalar(&mut self, v: f32) -> String {
        self.init("const", &[], &[v])
    }

    fn node_named(
        &mut self,
        op: &str,
        inputs: &[&str],
        attrs: Vec<AttributeProto>,
        output: &str,
    ) -> String {
        self.counter += 1;
        self.proto.node.push(NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.to_string()],
            name: format!("{op}_{}", self.counter),
            op_type: op.into(),
            attribute: attrs,
            ..Default::default()
        });
        output.to_string()
    }

    /// A node with one fresh output name.
    pub fn node(&mut self, op: &str, inputs: &[&str], attrs: Vec<AttributeProto>) -> String {
        let out = format!("{}_{}", op.to_lowercase(), self.counter + 1);
        self.node_named(op, inputs, attrs, &out)
    }

    pub fn add(&mut self, a: &str, b: &str) -> String {
        self.node("Add", &[a, b], vec![])
    }
    pub fn sub(&mut self, a: &str, b: &str) -> String {
        self.node("Sub", &[a, b], vec![])
    }
    pub fn mul(&mut self, a: &str, b: &str) -> String {
        self.node("Mul", &[a, b], vec![])
    }
    pub fn unary(&mut self, op: &str, a: &str) -> String {
        self.node(op, &[a], vec![])
    }

    /// `x W[:, c0..c0+cols] + b[c0..c0+cols]` of a Burn `Linear` (`W` is `[in, out]`).
    pub fn linear_cols(
        &mut self,
        x: &str,
        linear: &Linear,
        c0: usize,
        cols: usize,
        prefix: &str,
    ) -> Result<String, OnnxError> {
        let [d_in, d_out] = linear.weight.val().dims();
        if c0 + cols > d_out {
            return Err(OnnxError::Export(format!(
                "{prefix}: columns {c0}..{} of a {d_out}-wide layer",
                c0 + cols
            )));
        }
        let w = values(linear.weight.val())?;
        let sliced: Vec<f32> = (0..d_in)
            .flat_map(|i| w[i * d_out + c0..i * d_out + c0 + cols].iter().copied())
            .collect();
        let b = match &linear.bias {
            Some(b) => values(b.val())?[c0..c0 + cols].to_vec(),
            None => vec![0.0; cols],
        };
        let wn = self.init(&format!("{prefix}.weight"), &[d_in, cols], &sliced);
        let bn = self.init(&format!("{prefix}.bias"), &[cols], &b);
        Ok(self.node("Gemm", &[x, &wn, &bn], vec![]))
    }

    /// A whole Burn `Linear`.
    pub fn linear(&mut self, x: &str, linear: &Linear, prefix: &str) -> Result<String, OnnxError> {
        let [_, d_out] = linear.weight.val().dims();
        self.linear_cols(x, linear, 0, d_out, prefix)
    }

    /// `LayerNormalization` over the last axis with the module's gain and bias.
    pub fn layer_norm(
        &mut self,
        x: &str,
        ln: &LayerNorm,
        prefix: &str,
    ) -> Result<String, OnnxError> {
        let gamma = values(ln.gamma.val())?;
        let beta = match &ln.beta {
            Some(b) => values(b.val())?,
            None => vec![0.0; gamma.len()],
        };
        let g = self.init(&format!("{prefix}.gamma"), &[gamma.len()], &gamma);
        let b = self.init(&format!("{prefix}.beta"), &[beta.len()], &beta);
        Ok(self.node(
            "LayerNormalization",
            &[x, &g, &b],
            vec![
                attr_int("axis", -1),
                attr_float("epsilon", layer_norm_epsilon() as f32),
            ],
        ))
    }

    /// `BatchNormalization` with the running statistics (inference mode).
    pub fn batch_norm(
        &mut self,
        x: &str,
        bn: &BatchNorm,
        prefix: &str,
    ) -> Result<String, OnnxError> {
        let gamma = values(bn.gamma.val())?;
        let beta = values(bn.beta.val())?;
        let mean = values(bn.running_mean.value())?;
        let var = values(bn.running_var.value())?;
        let c = gamma.len();
        let names = [
            ("gamma", gamma),
            ("beta", beta),
            ("mean", mean),
            ("var", var),
        ]
        .map(|(n, v)| self.init(&format!("{prefix}.{n}"), &[c], &v));
        Ok(self.node(
            "BatchNormalization",
            &[x, &names[0], &names[1], &names[2], &names[3]],
            vec![attr_float("epsilon", bn.epsilon as f32)],
        ))
    }
}
