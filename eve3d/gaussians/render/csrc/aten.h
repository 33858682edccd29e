// What the kernels' wrappers use of ATen: tensors with their methods, the type dispatch and
// the few factory functions called, each from its own header. All of ATen (torch/types.h) was
// most of each file's compile time (docs/development.md, "Set-up").
#pragma once

#include <ATen/core/Tensor.h>
#include <ATen/Dispatch.h>
#include <ATen/ops/cat.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/empty_like.h>
#include <ATen/ops/from_blob.h>
#include <ATen/ops/ones.h>
#include <ATen/ops/scalar_tensor.h>
#include <ATen/ops/zeros.h>
#include <ATen/ops/zeros_like.h>
