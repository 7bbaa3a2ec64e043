// The names of every enum option, as the CLI and the Python module spell them, in one table per
// enum (help order), with the lookups both front ends use.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "vdbrecon/decimate.h"
#include "vdbrecon/fusion.h"
#include "vdbrecon/io.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/normals.h"
#include "vdbrecon/pipeline.h"

namespace vdbrecon {

/// (name, value) pairs of an enum option.
template <typename E>
using Choices = std::vector<std::pair<std::string, E>>;

inline const Choices<NormalMode>& normal_mode_choices() {
    static const Choices<NormalMode> c = {
        {"auto", NormalMode::automatic}, {"estimate", NormalMode::estimate}, {"keep", NormalMode::keep}};
    return c;
}
inline const Choices<OrientRule>& orient_rule_choices() {
    static const Choices<OrientRule> c = {{"auto", OrientRule::automatic},
                                          {"mst", OrientRule::mst}};
    return c;
}
inline const Choices<ScaleMode>& scale_mode_choices() {
    static const Choices<ScaleMode> c = {
        {"auto", ScaleMode::automatic}, {"knn", ScaleMode::knn}, {"none", ScaleMode::none}};
    return c;
}
inline const Choices<StreamMode>& stream_mode_choices() {
    static const Choices<StreamMode> c = {
        {"auto", StreamMode::automatic}, {"on", StreamMode::always}, {"off", StreamMode::never}};
    return c;
}
inline const Choices<KnnBackend>& knn_backend_choices() {
    static const Choices<KnnBackend> c = {{"grid", KnnBackend::grid}, {"flann", KnnBackend::flann}};
    return c;
}
inline const Choices<Mesher>& mesher_choices() {
    static const Choices<Mesher> c = {
        {"dual", Mesher::dual}, {"vdb", Mesher::vdb}, {"mc", Mesher::mc}, {"dc", Mesher::dc}};
    return c;
}
inline const Choices<DepthKind>& depth_kind_choices() {
    static const Choices<DepthKind> c = {{"planar", DepthKind::planar}, {"ray", DepthKind::ray}};
    return c;
}
inline const Choices<Placement>& placement_choices() {
    static const Choices<Placement> c = {{"edge", Placement::edge}, {"free", Placement::free}};
    return c;
}
inline const Choices<FusionRule>& fusion_rule_choices() {
    static const Choices<FusionRule> c = {{"splat", FusionRule::splat}, {"tsdf", FusionRule::tsdf}};
    return c;
}
inline const Choices<NonFinitePolicy>& non_finite_choices() {
    static const Choices<NonFinitePolicy> c = {{"drop", NonFinitePolicy::drop},
                                               {"error", NonFinitePolicy::error}};
    return c;
}
inline const Choices<PlyEncoding>& ply_encoding_choices() {
    static const Choices<PlyEncoding> c = {
        {"binary_little_endian", PlyEncoding::binary_little_endian},
        {"binary_big_endian", PlyEncoding::binary_big_endian},
        {"ascii", PlyEncoding::ascii}};
    return c;
}

/// The names joined by `sep`, each between `quote`s: "auto|estimate|keep", "'a', 'b'".
template <typename E>
std::string choice_list(const Choices<E>& choices, const char* sep, const char* quote = "") {
    std::string s;
    for (const auto& c : choices) s += (s.empty() ? "" : sep) + (quote + c.first + quote);
    return s;
}

/// The name of a value ("?" for a value without one).
template <typename E>
std::string choice_name(const Choices<E>& choices, E value) {
    for (const auto& c : choices) {
        if (c.second == value) return c.first;
    }
    return "?";
}

/// The value of a name, or nullptr when no choice has it.
template <typename E>
const E* find_choice(const Choices<E>& choices, const std::string& name) {
    for (const auto& c : choices) {
        if (c.first == name) return &c.second;
    }
    return nullptr;
}

}  // namespace vdbrecon
