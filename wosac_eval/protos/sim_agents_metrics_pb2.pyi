from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class SimAgentMetricsConfig(_message.Message):
    __slots__ = ("linear_speed", "linear_acceleration", "angular_speed", "angular_acceleration", "distance_to_nearest_object", "collision_indication", "time_to_collision", "distance_to_road_edge", "offroad_indication", "traffic_light_violation")
    class FeatureConfig(_message.Message):
        __slots__ = ("histogram", "kernel_density", "bernoulli", "independent_timesteps", "metametric_weight", "aggregate_objects")
        HISTOGRAM_FIELD_NUMBER: _ClassVar[int]
        KERNEL_DENSITY_FIELD_NUMBER: _ClassVar[int]
        BERNOULLI_FIELD_NUMBER: _ClassVar[int]
        INDEPENDENT_TIMESTEPS_FIELD_NUMBER: _ClassVar[int]
        METAMETRIC_WEIGHT_FIELD_NUMBER: _ClassVar[int]
        AGGREGATE_OBJECTS_FIELD_NUMBER: _ClassVar[int]
        histogram: SimAgentMetricsConfig.HistogramEstimate
        kernel_density: SimAgentMetricsConfig.KernelDensityEstimate
        bernoulli: SimAgentMetricsConfig.BernoulliEstimate
        independent_timesteps: bool
        metametric_weight: float
        aggregate_objects: bool
        def __init__(self, histogram: _Optional[_Union[SimAgentMetricsConfig.HistogramEstimate, _Mapping]] = ..., kernel_density: _Optional[_Union[SimAgentMetricsConfig.KernelDensityEstimate, _Mapping]] = ..., bernoulli: _Optional[_Union[SimAgentMetricsConfig.BernoulliEstimate, _Mapping]] = ..., independent_timesteps: bool = ..., metametric_weight: _Optional[float] = ..., aggregate_objects: bool = ...) -> None: ...
    class HistogramEstimate(_message.Message):
        __slots__ = ("min_val", "max_val", "num_bins", "additive_smoothing_pseudocount")
        MIN_VAL_FIELD_NUMBER: _ClassVar[int]
        MAX_VAL_FIELD_NUMBER: _ClassVar[int]
        NUM_BINS_FIELD_NUMBER: _ClassVar[int]
        ADDITIVE_SMOOTHING_PSEUDOCOUNT_FIELD_NUMBER: _ClassVar[int]
        min_val: float
        max_val: float
        num_bins: int
        additive_smoothing_pseudocount: float
        def __init__(self, min_val: _Optional[float] = ..., max_val: _Optional[float] = ..., num_bins: _Optional[int] = ..., additive_smoothing_pseudocount: _Optional[float] = ...) -> None: ...
    class KernelDensityEstimate(_message.Message):
        __slots__ = ("bandwidth",)
        BANDWIDTH_FIELD_NUMBER: _ClassVar[int]
        bandwidth: float
        def __init__(self, bandwidth: _Optional[float] = ...) -> None: ...
    class BernoulliEstimate(_message.Message):
        __slots__ = ("additive_smoothing_pseudocount",)
        ADDITIVE_SMOOTHING_PSEUDOCOUNT_FIELD_NUMBER: _ClassVar[int]
        additive_smoothing_pseudocount: float
        def __init__(self, additive_smoothing_pseudocount: _Optional[float] = ...) -> None: ...
    LINEAR_SPEED_FIELD_NUMBER: _ClassVar[int]
    LINEAR_ACCELERATION_FIELD_NUMBER: _ClassVar[int]
    ANGULAR_SPEED_FIELD_NUMBER: _ClassVar[int]
    ANGULAR_ACCELERATION_FIELD_NUMBER: _ClassVar[int]
    DISTANCE_TO_NEAREST_OBJECT_FIELD_NUMBER: _ClassVar[int]
    COLLISION_INDICATION_FIELD_NUMBER: _ClassVar[int]
    TIME_TO_COLLISION_FIELD_NUMBER: _ClassVar[int]
    DISTANCE_TO_ROAD_EDGE_FIELD_NUMBER: _ClassVar[int]
    OFFROAD_INDICATION_FIELD_NUMBER: _ClassVar[int]
    TRAFFIC_LIGHT_VIOLATION_FIELD_NUMBER: _ClassVar[int]
    linear_speed: SimAgentMetricsConfig.FeatureConfig
    linear_acceleration: SimAgentMetricsConfig.FeatureConfig
    angular_speed: SimAgentMetricsConfig.FeatureConfig
    angular_acceleration: SimAgentMetricsConfig.FeatureConfig
    distance_to_nearest_object: SimAgentMetricsConfig.FeatureConfig
    collision_indication: SimAgentMetricsConfig.FeatureConfig
    time_to_collision: SimAgentMetricsConfig.FeatureConfig
    distance_to_road_edge: SimAgentMetricsConfig.FeatureConfig
    offroad_indication: SimAgentMetricsConfig.FeatureConfig
    traffic_light_violation: SimAgentMetricsConfig.FeatureConfig
    def __init__(self, linear_speed: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ..., linear_acceleration: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ..., angular_speed: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ..., angular_acceleration: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ..., distance_to_nearest_object: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ..., collision_indication: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ..., time_to_collision: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ..., distance_to_road_edge: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ..., offroad_indication: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ..., traffic_light_violation: _Optional[_Union[SimAgentMetricsConfig.FeatureConfig, _Mapping]] = ...) -> None: ...

class SimAgentMetrics(_message.Message):
    __slots__ = ("scenario_id", "metametric", "average_displacement_error", "min_average_displacement_error", "linear_speed_likelihood", "linear_acceleration_likelihood", "angular_speed_likelihood", "angular_acceleration_likelihood", "distance_to_nearest_object_likelihood", "collision_indication_likelihood", "time_to_collision_likelihood", "distance_to_road_edge_likelihood", "offroad_indication_likelihood", "traffic_light_violation_likelihood", "simulated_collision_rate", "simulated_offroad_rate", "simulated_traffic_light_violation_rate")
    SCENARIO_ID_FIELD_NUMBER: _ClassVar[int]
    METAMETRIC_FIELD_NUMBER: _ClassVar[int]
    AVERAGE_DISPLACEMENT_ERROR_FIELD_NUMBER: _ClassVar[int]
    MIN_AVERAGE_DISPLACEMENT_ERROR_FIELD_NUMBER: _ClassVar[int]
    LINEAR_SPEED_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    LINEAR_ACCELERATION_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    ANGULAR_SPEED_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    ANGULAR_ACCELERATION_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    DISTANCE_TO_NEAREST_OBJECT_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    COLLISION_INDICATION_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    TIME_TO_COLLISION_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    DISTANCE_TO_ROAD_EDGE_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    OFFROAD_INDICATION_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    TRAFFIC_LIGHT_VIOLATION_LIKELIHOOD_FIELD_NUMBER: _ClassVar[int]
    SIMULATED_COLLISION_RATE_FIELD_NUMBER: _ClassVar[int]
    SIMULATED_OFFROAD_RATE_FIELD_NUMBER: _ClassVar[int]
    SIMULATED_TRAFFIC_LIGHT_VIOLATION_RATE_FIELD_NUMBER: _ClassVar[int]
    scenario_id: str
    metametric: float
    average_displacement_error: float
    min_average_displacement_error: float
    linear_speed_likelihood: float
    linear_acceleration_likelihood: float
    angular_speed_likelihood: float
    angular_acceleration_likelihood: float
    distance_to_nearest_object_likelihood: float
    collision_indication_likelihood: float
    time_to_collision_likelihood: float
    distance_to_road_edge_likelihood: float
    offroad_indication_likelihood: float
    traffic_light_violation_likelihood: float
    simulated_collision_rate: float
    simulated_offroad_rate: float
    simulated_traffic_light_violation_rate: float
    def __init__(self, scenario_id: _Optional[str] = ..., metametric: _Optional[float] = ..., average_displacement_error: _Optional[float] = ..., min_average_displacement_error: _Optional[float] = ..., linear_speed_likelihood: _Optional[float] = ..., linear_acceleration_likelihood: _Optional[float] = ..., angular_speed_likelihood: _Optional[float] = ..., angular_acceleration_likelihood: _Optional[float] = ..., distance_to_nearest_object_likelihood: _Optional[float] = ..., collision_indication_likelihood: _Optional[float] = ..., time_to_collision_likelihood: _Optional[float] = ..., distance_to_road_edge_likelihood: _Optional[float] = ..., offroad_indication_likelihood: _Optional[float] = ..., traffic_light_violation_likelihood: _Optional[float] = ..., simulated_collision_rate: _Optional[float] = ..., simulated_offroad_rate: _Optional[float] = ..., simulated_traffic_light_violation_rate: _Optional[float] = ...) -> None: ...

class SimAgentsBucketedMetrics(_message.Message):
    __slots__ = ("realism_meta_metric", "kinematic_metrics", "interactive_metrics", "map_based_metrics", "min_ade", "simulated_collision_rate", "simulated_offroad_rate", "simulated_traffic_light_violation_rate")
    REALISM_META_METRIC_FIELD_NUMBER: _ClassVar[int]
    KINEMATIC_METRICS_FIELD_NUMBER: _ClassVar[int]
    INTERACTIVE_METRICS_FIELD_NUMBER: _ClassVar[int]
    MAP_BASED_METRICS_FIELD_NUMBER: _ClassVar[int]
    MIN_ADE_FIELD_NUMBER: _ClassVar[int]
    SIMULATED_COLLISION_RATE_FIELD_NUMBER: _ClassVar[int]
    SIMULATED_OFFROAD_RATE_FIELD_NUMBER: _ClassVar[int]
    SIMULATED_TRAFFIC_LIGHT_VIOLATION_RATE_FIELD_NUMBER: _ClassVar[int]
    realism_meta_metric: float
    kinematic_metrics: float
    interactive_metrics: float
    map_based_metrics: float
    min_ade: float
    simulated_collision_rate: float
    simulated_offroad_rate: float
    simulated_traffic_light_violation_rate: float
    def __init__(self, realism_meta_metric: _Optional[float] = ..., kinematic_metrics: _Optional[float] = ..., interactive_metrics: _Optional[float] = ..., map_based_metrics: _Optional[float] = ..., min_ade: _Optional[float] = ..., simulated_collision_rate: _Optional[float] = ..., simulated_offroad_rate: _Optional[float] = ..., simulated_traffic_light_violation_rate: _Optional[float] = ...) -> None: ...
